"""Many devices and many processes on JAX's own runtime give the one-device answer (issue 21, item 4).

A 62-frame meeting (two batches of 31 frames on CPU) goes through
:func:`find_concurrences_over_frames` in fresh processes that import only the public API:

* one process with four forced host devices
  (``XLA_FLAGS=--xla_force_host_platform_device_count=4``): each batch is split over a
  ``Mesh`` of the four, eight frames a device;
* two CPU processes joined by ``jax.distributed.initialize``, each running one of the two
  batches (half the frames) and gathering the other's with ``process_allgather``.

Both must match this process's one-device result: the same modes, memberships, counts and
mutual gaze, and the same locations to within the mean-shift stopping step ``tol`` = 0.1 mm,
below which the search does not resolve a location anyway. Only float32 rounding differs:
four devices run a program of 8 frames rather than 31 (20 µm apart at most, measured), and
even the same program in another process differs by a few µm. Every child has a deadline,
so a hang fails the test instead of CI, and dumps its stacks first. Each child runs in a session
of its own and writes to a file: the two processes timed out together twice in the suite
(stop 56 here and in CI), never alone; a full pipe read too late, or a signal sent to the
tests' process group, can stall one while the other waits for it in a collective.
"""

from __future__ import annotations

import os
import pathlib
import signal
import socket
import subprocess
import sys
import time

import jax
import numpy as np
import pytest

from jaxgaze import ConcurrenceOptions, find_concurrences_over_frames
from jaxgaze._batching import _process_share, map_in_batches
from jaxgaze.simulate import simulate_scene

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="the children are Linux processes on local ports")

FRAMES = 62
DEADLINE_S = 300  # for all the children; a healthy run takes 20–40 s on two cores

# Every child dumps its threads' Python stacks on SIGUSR1, which the test sends before it kills a
# child that missed the deadline, so that a hang says where it was.
_DUMP_ON_SIGUSR1 = "import faulthandler, signal; faulthandler.register(signal.SIGUSR1, all_threads=True)\n"

_CHILD = _DUMP_ON_SIGUSR1 + """
import sys
import jax
import numpy as np

rays_file, out_file = sys.argv[1], sys.argv[2]
if len(sys.argv) > 3:  # one of several processes: join them before any computation
    jax.distributed.initialize(coordinator_address=sys.argv[3], num_processes=int(sys.argv[4]),
                               process_id=int(sys.argv[5]), initialization_timeout=120)
    print("joined", flush=True)  # where a hang was, with the stacks the test asks for

import jaxgaze
from jaxgaze.results import code

saved = np.load(rays_file)
rays = jaxgaze.GazeRays(saved["origins"], saved["directions"], saved["bandwidth"], saved["mask"])
found = jaxgaze.find_concurrences_over_frames(rays)
print("found", flush=True)
np.savez(out_file, devices=jax.local_device_count(), processes=jax.process_count(),
         process=jax.process_index(), count=found.count, **found._replace(result=code(found.result))._asdict())
print("saved", flush=True)
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(argv: list[str], log: pathlib.Path, devices: int) -> subprocess.Popen:
    """A child with ``devices`` CPU devices, in a session of its own (no signal sent to the tests' process group
    reaches it), writing to the file ``log``. A file, not a pipe: a child whose pipe filled would wait for the test
    to read it while the test waits for another child, which may be waiting for it in a collective."""
    with open(log, "w") as out:
        proc = subprocess.Popen(argv, env=_env(devices), stdin=subprocess.DEVNULL, stdout=out,
                                stderr=subprocess.STDOUT, text=True, start_new_session=True)
    proc.log = log
    return proc


def _answer(proc: subprocess.Popen, deadline: float) -> str | None:
    """The child's log once it exits, or ``None`` (and the child killed) if it is still running at ``deadline``.

    A child past the deadline is first asked for its stacks (SIGUSR1), which then end its log, printed here."""
    try:
        proc.wait(timeout=max(1.0, deadline - time.monotonic()))
        return proc.log.read_text()
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGUSR1)
        time.sleep(2.0)
        proc.kill()
        proc.wait()
        print(f"--- {proc.log.stem}: no answer by the deadline; its log ends ---\n{proc.log.read_text()[-6000:]}")
        return None


def _env(devices: int) -> dict:
    flags = [f for f in os.environ.get("XLA_FLAGS", "").split() if "device_count" not in f]
    if devices > 1:
        flags.append(f"--xla_force_host_platform_device_count={devices}")
    return dict(os.environ, JAX_PLATFORMS="cpu", XLA_FLAGS=" ".join(flags))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The children run while this process computes the one-device reference; then all are read."""
    folder = tmp_path_factory.mktemp("devices")
    rays = simulate_scene(jax.random.key(7), "meeting", num_frames=FRAMES).rays
    np.savez(folder / "rays.npz", origins=rays.origins, directions=rays.directions,
             bandwidth=rays.bandwidth, mask=rays.mask)
    (folder / "child.py").write_text(_CHILD)
    child = [sys.executable, str(folder / "child.py"), str(folder / "rays.npz")]
    address = f"127.0.0.1:{_free_port()}"
    started = {
        "four_devices": _start(child + [str(folder / "four_devices.npz")], folder / "four_devices.log", 4),
        **{f"process_{i}": _start(child + [str(folder / f"process_{i}.npz"), address, "2", str(i)],
                                  folder / f"process_{i}.log", 1)
           for i in range(2)},
    }
    try:
        assert jax.local_device_count() == 1 and jax.process_count() == 1
        reference = find_concurrences_over_frames(rays)
        failed, deadline = {}, time.monotonic() + DEADLINE_S
        for name, proc in started.items():
            log = _answer(proc, deadline)
            if log is None:
                failed[name] = f"no answer within {DEADLINE_S} s (hung?); its stacks are in the captured output"
            elif proc.returncode != 0:
                failed[name] = f"exit {proc.returncode}: {log[-2000:]}"
    finally:
        for proc in started.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert not failed, failed
    return reference, {name: dict(np.load(folder / f"{name}.npz")) for name in started}


def test_a_child_past_the_deadline_is_killed_with_its_stacks(tmp_path, capsys):
    """The deadline's path: the child is killed, and its log, with where it was, is printed."""
    proc = _start([sys.executable, "-c", _DUMP_ON_SIGUSR1 + "import time\nprint('joined', flush=True)\n"
                   "def waiting():\n    time.sleep(600)\nwaiting()\n"], tmp_path / "child.log", 1)
    started = time.monotonic()
    assert _answer(proc, started + 5.0) is None
    assert proc.returncode == -signal.SIGKILL and time.monotonic() - started < 60
    printed = capsys.readouterr().out
    assert "child: no answer by the deadline" in printed and "joined" in printed and "in waiting" in printed


def _assert_same_concurrences(found, reference, atol):
    np.testing.assert_array_equal(found["valid"], reference.valid)
    np.testing.assert_array_equal(found["count"], reference.count)
    np.testing.assert_array_equal(found["membership"], reference.membership)
    np.testing.assert_array_equal(found["mutual_gaze"], reference.mutual_gaze)
    valid = reference.valid
    np.testing.assert_allclose(found["locations"][valid], reference.locations[valid], rtol=0, atol=atol)


def test_four_devices_find_what_one_device_finds(runs):
    reference, found = runs
    four = found["four_devices"]
    assert int(four["devices"]) == 4 and int(four["processes"]) == 1
    assert reference.valid.sum() >= FRAMES  # every frame of the meeting has a concurrence
    _assert_same_concurrences(four, reference, atol=ConcurrenceOptions().tol)


def test_two_processes_find_what_one_process_finds(runs):
    reference, found = runs
    for i in range(2):
        part = found[f"process_{i}"]
        assert int(part["processes"]) == 2 and int(part["process"]) == i and int(part["devices"]) == 1
        _assert_same_concurrences(part, reference, atol=ConcurrenceOptions().tol)


def test_each_process_runs_a_contiguous_share_of_the_batches(monkeypatch):
    """Process p of P runs batches ⌊pS/P⌋ … ⌊(p+1)S/P⌋ − 1 and gets everyone's results back."""
    shares = [_process_share(7, p, 3) for p in range(3)]
    assert [list(range(7))[s] for s in shares] == [[0, 1], [2, 3], [4, 5, 6]]
    assert [list(range(1))[_process_share(1, p, 2)] for p in range(2)] == [[], [0]]

    import jaxgaze._batching as batching

    seen, gathered = [], {}
    monkeypatch.setattr(jax, "process_count", lambda: 2)
    monkeypatch.setattr(jax, "process_index", lambda: 1)
    monkeypatch.setattr(batching, "_gather_shares", lambda local, sizes: gathered.update(local=local, sizes=sizes))

    def double(part):
        seen.append(np.asarray(part["x"][:, 0]))
        return {"y": part["x"] * 2.0}

    x = np.arange(23 * 3, dtype=float).reshape(23, 3)
    map_in_batches(double, {"x": x}, 5)  # batches start at 0, 5, 10, 15, 20: process 1 takes 10, 15, 20
    assert [int(first[0]) for first in seen] == [30, 45, 60]
    assert gathered["sizes"] == [10, 13]
    np.testing.assert_array_equal(gathered["local"]["y"], 2 * x[10:])

    # One batch for two processes: process 1 runs it, process 0 brings an empty part of the right shape.
    monkeypatch.setattr(jax, "process_index", lambda: 0)
    map_in_batches(lambda part: {"y": part["x"] * 2.0}, {"x": x[:4]}, 5)
    assert gathered["sizes"] == [0, 4] and gathered["local"]["y"].shape == (0, 3)



# The joint model's SVI: the frame axis of the model's arrays split over four forced devices.
SVI_STEPS = 200
_SVI_CHILD = _DUMP_ON_SIGUSR1 + """
import sys
import jax
import numpy as np
from jax.sharding import NamedSharding, PartitionSpec
import jaxgaze.joint.infer as infer
from jaxgaze.joint import JointStart, fit_joint, joint_data

data_file, out_file, num_steps = sys.argv[1], sys.argv[2], int(sys.argv[3])
s = dict(np.load(data_file))
data = joint_data(s["eyes"], s["R"], s["gaze"], present=s["present"], speaking=s["speaking"],
                  measurement_scale=s["scale"], fps=float(s["fps"]))
start = JointStart(s["start_bias"], np.full(data.num_people, data.num_frames),
                   np.repeat(s["objects"][None], data.num_windows, axis=0), np.full(len(s["objects"]), data.num_frames))
run, out = infer._svi_run, {"devices": jax.local_device_count()}

for form in ("one", "four"):
    def spy(svi, key, arrays, *rest):  # record what the SVI steps run on; the one-device form gathers it on one device
        if form == "one":
            arrays = jax.device_put(arrays, jax.devices()[0])
        frames = arrays[:8]
        out[form + "_split"] = all(isinstance(a.sharding, NamedSharding) and a.sharding.spec == PartitionSpec("frames")
                                   for a in frames)
        out[form + "_array_devices"] = min(len(a.sharding.device_set) for a in frames)
        out[form + "_shard_frames"] = max(shard.data.shape[0] for a in frames for shard in a.addressable_shards)
        state, losses = run(svi, key, arrays, *rest)
        out[form + "_losses"] = np.asarray(losses)
        return state, losses

    infer._svi_run = spy
    post = fit_joint(data, key=jax.random.key(2), method="svi", num_steps=num_steps, frames_per_step=64, num_samples=20,
                     start=start)
    out[form + "_membership"] = post.membership
    out.update({form + "_draws_" + k: v for k, v in post.samples.items()})
np.savez(out_file, **out)
"""


def test_four_devices_fit_the_joint_model_as_one_device(tmp_path):
    """SVI on a 100-frame conversation (two blocks; one a step): the same ELBO trace and draws on 4 devices as on 1.

    One child with four forced devices fits twice: its SVI steps once on the arrays as
    ``fit_joint`` places them (frames padded to 128, 32 a device), once on the same arrays
    gathered on one device (the rest of the fit is the same single-device code either way,
    and compiled once). Tolerances are float32 rounding of differently partitioned programs
    over 200 Adam steps: losses ``rtol`` 1e-5 (1.4e-6 measured), draws and memberships
    ``atol`` 1e-5 (5e-7 measured).
    """
    from tests.helpers import conversation

    scene = conversation(num_people=3, duration_s=20.0, num_wearers=0)
    np.savez(tmp_path / "data.npz", eyes=scene.eye_positions, R=scene.R_world_from_head, gaze=scene.gaze_angles,
             present=scene.present, speaking=scene.speaking, scale=scene.measurement_scale, fps=scene.fps,
             objects=scene.object_positions, start_bias=0.5 * np.asarray(scene.bias))
    (tmp_path / "child.py").write_text(_SVI_CHILD)
    proc = _start([sys.executable, str(tmp_path / "child.py"), str(tmp_path / "data.npz"), str(tmp_path / "fits.npz"),
                   str(SVI_STEPS)], tmp_path / "child.log", 4)
    try:
        log = _answer(proc, time.monotonic() + DEADLINE_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    if log is None:
        pytest.fail(f"no answer within {DEADLINE_S} s (hung?); its stacks are in the captured output")
    assert proc.returncode == 0, log[-2000:]
    fits = dict(np.load(tmp_path / "fits.npz"))
    assert int(fits["devices"]) == 4
    assert not fits["one_split"] and int(fits["one_array_devices"]) == 1 and int(fits["one_shard_frames"]) == 128
    assert fits["four_split"] and int(fits["four_array_devices"]) == 4 and int(fits["four_shard_frames"]) == 32
    losses = fits["one_losses"]
    assert losses.shape == (SVI_STEPS,) and np.all(np.isfinite(losses))
    assert losses[-20:].mean() < losses[:20].mean()  # the fit moved
    np.testing.assert_allclose(fits["four_losses"], losses, rtol=1e-5)
    names = [k[len("one_"):] for k in fits if k.startswith("one_draws_")] + ["membership"]
    assert "draws_bias" in names and "draws_concurrence_locations" in names
    for name in names:
        assert np.all(np.isfinite(fits["one_" + name])), name
        np.testing.assert_allclose(fits["four_" + name], fits["one_" + name], rtol=0, atol=1e-5, err_msg=name)
