"""The generator honours its frame rate: every derivative in the files is the finite difference at that rate
(taken at a fixed 25 Hz, a 10 Hz recording's ``xAcceleration`` would be 2.5 times the finite difference of
``xVelocity``).
"""
import numpy as np
import pandas as pd
import pytest

from guardian.cli import main
from guardian.highd.generate import TrafficParams, generate


def _check_derivatives(folder, rate):
    meta = pd.read_csv(folder / "01_recordingMeta.csv")
    assert int(meta["frameRate"].iloc[0]) == rate
    tracks = pd.read_csv(folder / "01_tracks.csv")
    checked = 0
    for _, tr in tracks.groupby("id"):
        if len(tr) < 3:
            continue
        assert (np.diff(tr["frame"]) == 1).all()
        # as the generator differentiates: central differences inside, one-sided at the ends
        np.testing.assert_allclose(tr["xAcceleration"], np.gradient(tr["xVelocity"].to_numpy()) * rate, atol=6e-5)
        np.testing.assert_allclose(tr["yVelocity"], np.gradient(tr["y"].to_numpy()) * rate, atol=6e-3)
        np.testing.assert_allclose(tr["yAcceleration"], np.gradient(tr["yVelocity"].to_numpy()) * rate, atol=6e-5)
        # and the plain forward difference between two inner frames agrees with the mean of the two
        v, a = tr["xVelocity"].to_numpy(), tr["xAcceleration"].to_numpy()
        np.testing.assert_allclose((v[2] - v[0]) * rate / 2, a[1], atol=6e-5)
        checked += 1
    assert checked > 10
    return tracks


@pytest.mark.parametrize("rate", [10, 25])
def test_accelerations_are_finite_differences_at_the_frame_rate(tmp_path, rate):
    generate(tmp_path, 1, 0.25, seed=4, prm=TrafficParams(frame_rate=rate, warmup=20.0))
    tracks = _check_derivatives(tmp_path, rate)
    assert tracks["xAcceleration"].abs().max() > 0.1  # the traffic does accelerate


def test_the_cli_writes_the_frame_rate_asked_for(tmp_path):
    assert main(["highd", "generate", "--out", str(tmp_path), "--minutes", "0.2", "--frame-rate", "10"]) == 0
    _check_derivatives(tmp_path, 10)


@pytest.mark.parametrize("rate", [0, -5, 2.5, True])
def test_a_frame_rate_that_is_not_a_positive_whole_number_is_refused(rate):
    with pytest.raises(ValueError, match="frame_rate"):
        TrafficParams(frame_rate=rate)
