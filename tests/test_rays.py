"""Tests of jaxgaze.rays.GazeRays: validation, normalisation, padding, stacking,
indexing and pytree behaviour under jit / vmap / grad."""

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxgaze import GazeRays, saliency_field

NAN, INF = np.nan, np.inf
field = jax.jit(saliency_field)


def _good(n=4):
    rng = np.random.default_rng(n)
    origins = rng.normal(size=(n, 3))
    directions = rng.normal(size=(n, 3))
    bandwidth = rng.uniform(0.02, 0.2, size=n)
    return origins, directions, bandwidth


def _with(array, index, value):
    a = np.array(array, dtype=float)
    a[index] = value
    return a


# ---------------------------------------------------------------- validation: values

O, D, H = _good()

VALUE_CASES = [
    # (origins, directions, bandwidth, field named in the message, ray named)
    (_with(O, (2, 1), NAN), D, H, "origins", "2"),
    (_with(O, (1, 0), INF), D, H, "origins", "1"),
    (_with(O, (3, 2), -INF), D, H, "origins", "3"),
    (O, _with(D, (0, 2), NAN), H, "directions", "0"),
    (O, _with(D, (3, 1), INF), H, "directions", "3"),
    (O, D, _with(H, 1, NAN), "bandwidth", "1"),
    (O, D, _with(H, 2, INF), "bandwidth", "2"),
    (O, _with(D, 2, 0.0), H, "directions", "2"),  # zero-length direction
    (O, _with(D, 1, 1e-12), H, "directions", "1"),  # below the 1e-9 floor
    (O, D, _with(H, 3, 0.0), "bandwidth", "3"),  # non-positive bandwidth
    (O, D, _with(H, 0, -0.1), "bandwidth", "0"),
    (O, D, -0.05, "bandwidth", "0"),  # scalar, broadcast: the first ray is named
]


@pytest.mark.parametrize("origins, directions, bandwidth, field, ray", VALUE_CASES)
def test_value_errors_name_field_and_ray(origins, directions, bandwidth, field, ray):
    with pytest.raises(ValueError) as info:
        GazeRays(origins, directions, bandwidth)
    msg = str(info.value)
    assert field in msg
    assert re.search(rf"\bray {re.escape(ray)}\b", msg), msg


def test_value_error_message_kinds():
    with pytest.raises(ValueError, match="not finite"):
        GazeRays(_with(O, (0, 0), NAN), D, H)
    with pytest.raises(ValueError, match="zero length"):
        GazeRays(O, _with(D, 0, 0.0), H)
    with pytest.raises(ValueError, match="positive"):
        GazeRays(O, D, _with(H, 0, 0.0))


def test_value_error_names_batched_ray():
    origins = np.zeros((2, 3, 3))
    directions = np.ones((2, 3, 3))
    directions[1, 2] = 0.0
    with pytest.raises(ValueError, match=re.escape("directions of ray (1, 2)")):
        GazeRays(origins, directions, 0.1)


def test_first_offending_ray_is_named():
    with pytest.raises(ValueError, match=r"ray 1\b"):
        GazeRays(O, D, _with(_with(H, 1, -1.0), 3, -1.0))


# ---------------------------------------------------------------- validation: shapes


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(origins=np.zeros((4, 2)), directions=np.ones((4, 2))), "origins"),
        (dict(origins=np.zeros(3), directions=np.ones(3)), "origins"),  # no ray axis
        (dict(origins=np.zeros((4, 3)), directions=np.ones((3, 3))), "directions"),
        (dict(origins=np.zeros((4, 3)), directions=np.ones((4, 3)), mask=np.ones(3, bool)), "mask"),
        (dict(origins=np.zeros((4, 3)), directions=np.ones((4, 3)), mask=np.ones((4, 1), bool)), "mask"),
        (dict(origins=np.zeros((4, 3)), directions=np.ones((4, 3)), bandwidth=np.ones(3)), "bandwidth"),
        (dict(origins=np.zeros((4, 3)), directions=np.ones((4, 3)), bandwidth=np.ones((4, 2))), "bandwidth"),
        (dict(origins=np.zeros((2, 4, 3)), directions=np.ones((2, 4, 3)), bandwidth=np.ones((3, 4))), "bandwidth"),
    ],
)
def test_shape_errors_name_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        GazeRays(**kwargs)


# ---------------------------------------------------------------- construction


@settings(max_examples=40, deadline=None)
@given(
    st.lists(
        st.tuples(*[st.floats(-100, 100, allow_nan=False) for _ in range(3)])
        .map(np.array)
        .filter(lambda v: np.linalg.norm(v) > 1e-3),
        min_size=3,
        max_size=3,  # fixed N: one compile of each eager op
    )
)
def test_directions_are_normalised(dirs):
    dirs = np.stack(dirs)
    rays = GazeRays(np.zeros_like(dirs), dirs, 0.1)
    got = np.asarray(rays.directions, float)
    np.testing.assert_allclose(np.linalg.norm(got, axis=-1), 1.0, rtol=1e-6)
    np.testing.assert_allclose(got, dirs / np.linalg.norm(dirs, axis=-1, keepdims=True), atol=1e-6)


def test_bandwidth_broadcast_dtype_and_defaults():
    rays = GazeRays(np.zeros((5, 3), dtype=int), np.ones((5, 3), dtype=int))
    assert jnp.issubdtype(rays.origins.dtype, jnp.floating)
    assert rays.directions.dtype == rays.origins.dtype == rays.bandwidth.dtype
    assert rays.bandwidth.shape == (5,)
    np.testing.assert_allclose(rays.bandwidth, 0.05, rtol=1e-7)
    assert rays.mask.dtype == jnp.bool_ and bool(rays.mask.all())
    assert rays.num_rays == 5 and rays.batch_shape == ()
    np.testing.assert_allclose(GazeRays(O, D, 0.1).bandwidth, np.full(4, 0.1), rtol=1e-7)
    np.testing.assert_allclose(GazeRays(O, D, H).bandwidth, H, rtol=1e-6)
    np.testing.assert_allclose(GazeRays(O, D, H).origins, O, rtol=1e-6)


def test_padded_rays_are_not_validated_and_replaced():
    origins = _with(O, 1, NAN)
    directions = _with(_with(D, 1, INF), 3, 0.0)
    bandwidth = _with(_with(H, 1, -1.0), 3, NAN)
    mask = np.array([True, False, True, False])
    rays = GazeRays(origins, directions, bandwidth, mask)  # must not raise
    for name in ("origins", "directions", "bandwidth"):
        assert np.all(np.isfinite(getattr(rays, name))), name
    np.testing.assert_array_equal(rays.mask, mask)
    for i in (1, 3):  # placeholders
        np.testing.assert_array_equal(rays.origins[i], [0.0, 0.0, 0.0])
        np.testing.assert_array_equal(rays.directions[i], [1.0, 0.0, 0.0])
        assert float(rays.bandwidth[i]) == 1.0
    for i in (0, 2):  # real rays untouched
        np.testing.assert_allclose(rays.origins[i], O[i], rtol=1e-6)
        np.testing.assert_allclose(rays.directions[i], D[i] / np.linalg.norm(D[i]), rtol=1e-6)
    # a masked bad ray does not hide a real bad ray
    with pytest.raises(ValueError, match=r"bandwidth of ray 2\b"):
        GazeRays(origins, directions, _with(bandwidth, 2, 0.0), mask)


def test_host_inputs_compile_nothing_and_match_device_inputs():
    # Issue 21 (time to first answer): rays from numpy arrays are prepared on the host, so a
    # new number of rays compiles no program; device arrays give the same rays.
    compiled = []

    def listener(event, duration_secs, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(event)

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        host = [GazeRays(*_good(n), mask=np.arange(n) != 1) for n in (3, 5, 6)]
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert compiled == []
    origins, directions, bandwidth = _good(5)
    device = GazeRays(jnp.asarray(origins), jnp.asarray(directions), jnp.asarray(bandwidth),
                      jnp.asarray(np.arange(5) != 1))
    for name in ("origins", "directions", "bandwidth", "mask"):
        got, want = getattr(host[1], name), getattr(device, name)
        assert isinstance(got, jax.Array) and got.dtype == want.dtype and got.shape == want.shape, name
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-6, atol=1e-7, err_msg=name)


# ---------------------------------------------------------------- stack and indexing


def _frames():
    rng = np.random.default_rng(7)
    sizes = [3, 1, 2]
    return [GazeRays(rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.uniform(0.05, 0.1, n)) for n in sizes], sizes


def test_stack_pads_frames():
    frames, sizes = _frames()
    rec = GazeRays.stack(frames)
    assert rec.batch_shape == (3,) and rec.num_rays == 3
    assert rec.origins.shape == (3, 3, 3) and rec.bandwidth.shape == (3, 3) and rec.mask.shape == (3, 3)
    np.testing.assert_array_equal(rec.mask, [[1, 1, 1], [1, 0, 0], [1, 1, 0]])
    for t, (f, n) in enumerate(zip(frames, sizes)):
        np.testing.assert_allclose(rec.origins[t, :n], f.origins)
        np.testing.assert_allclose(rec.directions[t, :n], f.directions, rtol=1e-6)
        np.testing.assert_allclose(rec.bandwidth[t, :n], f.bandwidth)
        # padding holds the placeholders, never NaN
        np.testing.assert_array_equal(rec.directions[t, n:], np.tile([1.0, 0.0, 0.0], (3 - n, 1)))
        np.testing.assert_array_equal(rec.bandwidth[t, n:], 1.0)


def test_stack_errors():
    frames, _ = _frames()
    with pytest.raises(ValueError):
        GazeRays.stack([])
    with pytest.raises(ValueError, match="frame 1"):
        GazeRays.stack([frames[0], GazeRays.stack(frames)])


def test_indexing():
    frames, sizes = _frames()
    rec = GazeRays.stack(frames)
    for t, n in enumerate(sizes):
        frame = rec[t]
        assert isinstance(frame, GazeRays)
        assert frame.batch_shape == () and frame.num_rays == 3
        np.testing.assert_allclose(frame.origins[:n], frames[t].origins)
        assert int(frame.mask.sum()) == n
    sub = rec[1:]
    assert sub.batch_shape == (2,)
    np.testing.assert_array_equal(sub.mask, rec.mask[1:])
    with pytest.raises(IndexError):
        frames[0][0]


# ---------------------------------------------------------------- pytree: jit / vmap / grad


def test_pytree_leaves():
    rays = GazeRays(O, D, H)
    leaves, treedef = jax.tree_util.tree_flatten(rays)
    assert len(leaves) == 4
    back = jax.tree_util.tree_unflatten(treedef, leaves)
    np.testing.assert_array_equal(back.directions, rays.directions)


def test_construction_inside_jit():
    mask = np.array([True, True, False, True])
    eager = GazeRays(O, D, H, mask)
    traced = jax.jit(lambda o, d, h, m: GazeRays(o, d, h, m))(O, D, H, mask)
    for name in ("origins", "directions", "bandwidth", "mask"):
        np.testing.assert_allclose(getattr(traced, name), getattr(eager, name), rtol=1e-6)
    # values cannot be checked on tracers: no crash, and padded NaN still replaced
    bad = jax.jit(lambda o, m: GazeRays(o, D, 0.1, m))(_with(O, 2, NAN), mask)
    assert np.all(np.isfinite(bad.origins))
    # shape checks still run on tracers
    with pytest.raises(ValueError, match="mask"):
        jax.jit(lambda o, m: GazeRays(o, D, 0.1, m))(O, mask[:3])


def test_jit_passes_rays_through():
    rays = GazeRays(O, D, H)
    out = jax.jit(lambda r: r)(rays)
    assert isinstance(out, GazeRays)
    np.testing.assert_allclose(out.directions, rays.directions)
    shifted = jax.jit(lambda r, s: GazeRays(r.origins + s, r.directions, r.bandwidth, r.mask))(rays, 1.0)
    np.testing.assert_allclose(shifted.origins, rays.origins + 1.0, rtol=1e-6)


def test_vmap_over_frames():
    frames, _ = _frames()
    rec = GazeRays.stack(frames)
    x = jnp.array([0.3, -0.2, 0.5])
    per_frame = jax.jit(jax.vmap(lambda r: saliency_field(r, x)))(rec)
    assert per_frame.shape == (3,)
    np.testing.assert_allclose(per_frame, [field(f, x) for f in frames], rtol=1e-5)


def test_vmap_construction():
    rng = np.random.default_rng(8)
    o, d = rng.normal(size=(5, 4, 3)), rng.normal(size=(5, 4, 3))
    rays = jax.jit(jax.vmap(lambda o, d: GazeRays(o, d, 0.1)))(o, d)
    assert rays.batch_shape == (5,) and rays.bandwidth.shape == (5, 4)
    np.testing.assert_allclose(rays.directions, GazeRays(o, d, 0.1).directions, rtol=1e-6)


def test_grad_through_rays():
    x = jnp.array([1.0, 0.5, 0.2])

    def f(origins):
        return saliency_field(GazeRays(origins, D, H), x)

    grad = jax.jit(jax.grad(f))(jnp.asarray(O, jnp.float32))
    assert grad.shape == O.shape and np.all(np.isfinite(grad))


def test_from_rows_equals_stacking_frames_in_row_order():
    rng = np.random.default_rng(0)
    frames = np.array([7, 3, 7, 7, 3, 9])
    origins, directions = rng.normal(size=(6, 3)), rng.normal(size=(6, 3))
    bandwidth = rng.uniform(0.02, 0.1, 6)
    frame_ids, rays = GazeRays.from_rows(frames, origins, directions, bandwidth)
    np.testing.assert_array_equal(frame_ids, [3, 7, 9])
    expected = GazeRays.stack([GazeRays(origins[frames == f], directions[frames == f], bandwidth[frames == f])
                               for f in (3, 7, 9)])
    for field in ("origins", "directions", "bandwidth", "mask"):
        np.testing.assert_allclose(np.asarray(getattr(rays, field)), np.asarray(getattr(expected, field)), atol=1e-6)
    with pytest.raises(ValueError, match="zero length"):
        GazeRays.from_rows([1, 1], origins[:2], np.zeros((2, 3)))


def test_check_units_ignores_padding_and_names_the_unit():
    """Padded slots carry a placeholder bandwidth of 1 rad: only real rays are checked."""
    import warnings

    from jaxgaze.rays import UnitWarning, check_bandwidth, check_units

    two = GazeRays([[0.0, 0, 1.6], [2.0, 0, 1.6]], [[1.0, 0, 0], [-1.0, 0, 0]], 0.05)
    three = GazeRays([[0.0, 0, 1.6], [2.0, 0, 1.6], [1.0, 3.0, 1.2]], [[1.0, 0, 0], [-1.0, 0, 0], [0, -1.0, 0]], 0.05)
    recording = GazeRays.stack([two, three])
    assert float(recording.bandwidth[0, 2]) == 1.0 and not bool(recording.mask[0, 2])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_units(recording)
        check_bandwidth(0.99)
    with pytest.raises(ValueError, match=r"--bandwidth 1 rad \(57°\) is no gaze cone width.*degrees\?"):
        check_bandwidth(1.0, "--bandwidth")
    with pytest.warns(UnitWarning, match=r"bandwidth reaches 0.6 rad"):
        check_units(GazeRays(two.origins, two.directions, 0.6))
    with pytest.warns(UnitWarning, match=r"spread over 150 m"):
        check_units(GazeRays([[0.0, 0, 1.6], [150.0, 0, 1.6]], two.directions, 0.05))
