"""The joint model's output files (jaxgaze.io.joint): the per-frame CSV round-trips, and neither
writer leaves a file behind when writing fails. A small fake posterior keeps it fast."""

import csv
import os
from types import SimpleNamespace

import numpy as np
import pytest

from jaxgaze.io.joint import (JOINT_FRAME_COLUMNS, joint_frame_columns, read_speech, write_joint_frames,
                              write_joint_netcdf)
from jaxgaze.io.speech import SpeechFileError, read_rttm

DATA = os.path.join(os.path.dirname(os.path.dirname(__file__)), "data")

PEOPLE = ("ann", "ben", "cat lee")
CANDIDATES = PEOPLE + ("concurrence 0", "elsewhere")


def _posterior(T=6, seed=0):
    """A fake posterior: random memberships (0 for an absent person) and mutual-gaze probabilities."""
    rng = np.random.default_rng(seed)
    P, C = len(PEOPLE), len(CANDIDATES)
    membership = rng.random((T, P, C))
    for i in range(P):
        membership[:, i, i] = 0.0  # nobody looks at themselves
    membership /= membership.sum(-1, keepdims=True)
    membership[2, 1] = 0.0  # ben absent at row 2
    looks = membership[..., :P]
    mutual = looks * np.swapaxes(looks, 1, 2)
    mutual[3] = 0.0  # no chance of mutual gaze at row 3
    mutual[4] = 1e-9  # … nor, to 6 decimals, at row 4
    return SimpleNamespace(people=PEOPLE, candidates=CANDIDATES, membership=membership, mutual=mutual, sampler=None)


def _read(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_frames_round_trip(tmp_path):
    post = _posterior()
    T, P, _ = post.membership.shape
    frames, times = np.arange(10, 10 + T), np.arange(T) / 5.0
    path = tmp_path / "frames.csv"
    assert write_joint_frames(path, post, frames, times) == T * P
    rows = _read(path)
    columns = joint_frame_columns(CANDIDATES)
    with open(path, newline="") as f:
        assert tuple(next(csv.reader(f))) == columns
    assert columns[:6] == JOINT_FRAME_COLUMNS[:6] and columns[-2:] == JOINT_FRAME_COLUMNS[-2:]
    assert "p_cat_lee" in columns and "p_concurrence_0" in columns and "p_elsewhere" in columns
    assert len(rows) == T * P
    p_columns = [c for c in columns if c.startswith("p_") and c != "p_mutual"]
    for n, row in enumerate(rows):
        t, i = divmod(n, P)
        assert int(row["frame"]) == frames[t] and float(row["time"]) == pytest.approx(times[t])
        assert row["person"] == PEOPLE[i]
        if t == 2 and i == 1:
            assert row["present"] == "0"
            assert all(row[c] == "" for c in columns[4:])
            continue
        assert row["present"] == "1"
        p = np.array([float(row[c]) for c in p_columns])
        np.testing.assert_allclose(p, post.membership[t, i], atol=1e-6)
        assert p.sum() == pytest.approx(1.0, abs=1e-5)
        best = int(np.argmax(post.membership[t, i]))
        assert row["target"] == CANDIDATES[best]
        assert float(row["probability"]) == pytest.approx(post.membership[t, i, best], abs=1e-6)
        if t in (3, 4):
            assert row["mutual_with"] == "" and float(row["p_mutual"]) == 0.0
        else:
            j = int(np.argmax(np.where(np.arange(P) == i, -1.0, post.mutual[t, i])))
            assert row["mutual_with"] == PEOPLE[j] != PEOPLE[i]
            assert float(row["p_mutual"]) == pytest.approx(post.mutual[t, i, j], abs=1e-6)


def test_frames_checks_shapes_and_names(tmp_path):
    post = _posterior()
    path = tmp_path / "frames.csv"
    with pytest.raises(ValueError, match="one value per frame"):
        write_joint_frames(path, post, range(3), range(3))
    with pytest.raises(ValueError, match="membership must have shape"):
        write_joint_frames(path, SimpleNamespace(**{**vars(post), "candidates": CANDIDATES[:-1]}), range(6),
                           range(6))
    with pytest.raises(ValueError, match="same column"):
        joint_frame_columns(("a b", "a_b", "elsewhere"))
    assert not os.path.exists(path)


class _Boom(Exception):
    pass


def _exploding_frames(T, at, error):
    """Frame ids whose ``at``-th raises ``error`` when the writer reads it (half-way through the file)."""

    class Frame:
        def __init__(self, value):
            self.value = value

        def __int__(self):
            if self.value == at:
                raise error("disk on fire")
            return self.value

    return [Frame(t) for t in range(T)]


@pytest.mark.parametrize("error", [_Boom, KeyboardInterrupt])
def test_frames_atomic(tmp_path, error):
    post = _posterior()
    path = tmp_path / "frames.csv"
    frames = _exploding_frames(6, 4, error)
    with pytest.raises(error):
        write_joint_frames(path, post, frames, np.arange(6.0))
    assert os.listdir(tmp_path) == []
    # An existing file is left untouched.
    path.write_text("old\n")
    with pytest.raises(error):
        write_joint_frames(path, post, frames, np.arange(6.0))
    assert path.read_text() == "old\n" and os.listdir(tmp_path) == ["frames.csv"]


def _idata():
    import arviz as az

    rng = np.random.default_rng(1)
    return az.from_dict(posterior={"bias": rng.normal(size=(1, 8, 3, 2)), "cone_width": rng.random((1, 8, 3))},
                        coords={"person": list(PEOPLE), "angle": ["yaw", "tilt"]},
                        dims={"bias": ["person", "angle"], "cone_width": ["person"]})


def test_netcdf_round_trip(tmp_path):
    import arviz as az

    idata = _idata()
    path = tmp_path / "joint.nc"
    path.write_text("an older file")
    assert write_joint_netcdf(path, SimpleNamespace(sampler=SimpleNamespace(idata=idata))) == str(path)
    back = az.from_netcdf(path)
    np.testing.assert_allclose(back.posterior["bias"].values.reshape(1, 8, 3, 2), idata.posterior["bias"].values)
    assert list(back.posterior["person"].values) == list(PEOPLE)
    assert os.listdir(tmp_path) == ["joint.nc"]


def test_netcdf_atomic(tmp_path):
    class Broken:
        def to_netcdf(self, filename):
            with open(filename, "w") as f:
                f.write("half a file")
            raise _Boom("disk on fire")

    path = tmp_path / "joint.nc"
    with pytest.raises(_Boom):
        write_joint_netcdf(path, SimpleNamespace(sampler=SimpleNamespace(idata=Broken())))
    assert os.listdir(tmp_path) == []


def test_read_speech_refuses_several_recordings_as_read_rttm_does(tmp_path):
    """AMI-style RTTM of 3 recordings: one error, whatever the extension, and file_id selects one."""
    ami = os.path.join(DATA, "ami_style_three_recordings.rttm")
    copy = tmp_path / "speech.txt"  # read as RTTM by its SPEAKER lines
    copy.write_text(open(ami).read())
    with pytest.raises(SpeechFileError) as direct:
        read_rttm(ami)
    for path in (ami, copy):
        with pytest.raises(SpeechFileError) as info:
            read_speech(path)
        assert info.value.what == direct.value.what and info.value.line == 6
    segments = read_speech(copy, file_id="IS1008a")
    assert segments.speaker == ("FIE038", "MIE080", "FIE038")
    csv_path = tmp_path / "speech.csv"
    csv_path.write_text("start,end,speaker\n0,1,A\n")
    with pytest.raises(SpeechFileError, match=r"a file id \(--speech-file-id\) is only for RTTM speech files"):
        read_speech(csv_path, file_id="IS1008a")
