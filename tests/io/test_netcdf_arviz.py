"""The posterior files we write, read back with arviz's own tools (issue 34, item 7).

``az.summary`` and ``az.rhat`` on a written ``.nc`` must give the split r-hat that our JSON and
summary lines report, without a warning (arviz refuses one chain: r-hat NaN and a shape warning),
and the ESS too where the posterior is judged in the layout written; every variable says its units.
"""

import logging
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

from jaxgaze.io.joint import write_joint_netcdf
from jaxgaze.nuts import mixing_diagnostics, posterior_summary


@pytest.fixture
def arviz_log():
    """Every record arviz logs (its own Logger instance, not logging.getLogger) while the test runs."""
    import arviz

    records = []
    handler = logging.Handler()
    handler.emit = records.append
    arviz._log.addHandler(handler)
    yield records
    arviz._log.removeHandler(handler)


def _one_chain_joint_idata(num_draws=400):
    """A single NUTS chain of two joint sites, AR(1) draws (autocorrelated, as NUTS gives), with sample stats."""
    import arviz as az

    rng = np.random.default_rng(3)
    noise = rng.normal(size=(1, num_draws, 3, 2))
    bias = np.zeros_like(noise)
    for i in range(num_draws):
        bias[:, i] = 0.6 * bias[:, i - 1] + noise[:, i] if i else noise[:, i]
    stats = {"diverging": np.zeros((1, num_draws), bool), "acceptance_rate": np.full((1, num_draws), 0.9)}
    return az.from_dict(posterior={"bias": 0.02 * bias, "cone_width": 0.1 + 0.01 * rng.random((1, num_draws, 3))},
                        sample_stats=stats, coords={"person": ["a", "b", "c"], "angle": ["yaw", "tilt"]},
                        dims={"bias": ["person", "angle"], "cone_width": ["person"]})


def test_joint_netcdf_gives_arviz_our_diagnostics(tmp_path, arviz_log):
    """One chain written, read back: arviz's r-hat is finite and the split r-hat we report, no warning."""
    import arviz as az

    idata = _one_chain_joint_idata()
    names = ["bias", "cone_width"]
    ours = posterior_summary(idata, names)  # what the joint JSON and summary report
    diagnostics = mixing_diagnostics(idata, names)
    path = tmp_path / "joint.nc"
    write_joint_netcdf(path, SimpleNamespace(sampler=SimpleNamespace(idata=idata)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = az.from_netcdf(path)
        table = az.summary(back, var_names=names, round_to="none")
        rhat = az.rhat(back, var_names=names)
        ess = az.ess(back, var_names=names)
    assert arviz_log == []
    assert np.all(np.isfinite(table["r_hat"]))
    np.testing.assert_allclose(table["r_hat"], ours.loc[table.index, "r_hat"], rtol=0, atol=1e-6)
    # The joint model judges the ESS of its whole chain, which arviz on the halves estimates differently (here by
    # up to 20%); the calibration posterior is judged on the halves: equal there (tests/cli/test_calibrate.py).
    assert float(table["r_hat"].max()) == pytest.approx(diagnostics.max_rhat, abs=1e-6)
    assert float(rhat["cone_width"].max()) == pytest.approx(float(table.filter(like="cone_width", axis=0)["r_hat"].max()),
                                                            abs=1e-9)
    assert float(ess["bias"].min()) == pytest.approx(float(table.filter(like="bias", axis=0)["ess_bulk"].min()))
    # judged on the layout written (as the calibration posterior is), the ESS is arviz's too
    from jaxgaze.nuts import split_chains

    np.testing.assert_allclose(posterior_summary(split_chains(idata), names).loc[table.index, ["ess_bulk", "ess_tail"]],
                               table[["ess_bulk", "ess_tail"]], rtol=1e-9)
    # The mean, sd and HDI are those of every draw, and the file says how its chains relate to the sampler's.
    np.testing.assert_allclose(table["mean"], ours.loc[table.index, "mean"], rtol=1e-6, atol=1e-9)
    assert back.posterior.attrs["sampler_chains"] == 1 and back.posterior.sizes["chain"] == 2
    assert diagnostics.chains == 1
    for name, units in (("bias", "rad"), ("cone_width", "rad")):
        assert back.posterior[name].attrs["units"] == units


def test_split_chains_keeps_every_draw_in_order():
    """Chains 2k and 2k+1 of the split layout are the first and second half of sampler chain k."""
    from jaxgaze.nuts import split_chains

    idata = _one_chain_joint_idata(num_draws=10)
    split = split_chains(idata)
    np.testing.assert_array_equal(split.posterior["bias"].values.reshape(1, 10, 3, 2), idata.posterior["bias"].values)
    np.testing.assert_array_equal(split.sample_stats["diverging"].values.reshape(1, 10),
                                  idata.sample_stats["diverging"].values)
    assert split_chains(split) is split  # already split: unchanged
