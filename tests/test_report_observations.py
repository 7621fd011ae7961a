"""The identify JSON's per-observation block: what `calbench view --identified` draws."""

from __future__ import annotations

import json

import numpy as np
from conftest import PAPER

from calbench.bench.log import read_log
from calbench.bench.view import measured_deflections
from calbench.identify.cli import main
from calbench.identify.core import from_log


def test_observations_are_measured_minus_residual_and_match_the_chi2(tmp_path):
    log, rep = tmp_path / "p.mcap", tmp_path / "id.json"
    assert main(["simulate", str(PAPER), "--out", str(log)]) == 0
    assert main(["identify", str(log), "--json", str(rep)]) == 0
    d = json.loads(rep.read_text())
    obs = d["observations"]
    assert len(obs) == d["n_observations"]
    m = np.array([o["measured"] for o in obs])
    p = np.array([o["predicted"] for o in obs])
    r = np.array([o["residual"] for o in obs])
    np.testing.assert_allclose(m - p, r, atol=1e-15)
    # the residuals are the report's: same RMS
    assert abs(np.sqrt(np.mean(r**2)) - d["residual_rms"]) < 1e-12
    # the model explains millimetre deflections to the noise: a deflection is the difference of
    # two readings (sigma * sqrt 2 per axis); 5 such sigmas over ~130 coordinates fails w.p. ~1e-4
    assert np.abs(m).max() > 1e-3
    assert np.abs(r).max() < 5 * np.sqrt(2) * d["noise_sigma"]


def test_viewer_and_identification_average_alike(tmp_path):
    """One averaging function: the viewer's measured deflections are identify's dp, exactly."""
    path = tmp_path / "p.mcap"
    assert main(["simulate", str(PAPER), "--out", str(path)]) == 0
    log = read_log(path)
    obs = from_log(log)
    view = measured_deflections(log)
    assert obs.n_obs() == sum(len(v) for v in view.values())
    for (pose, refl), dp in zip(obs.labels, obs.dp):
        np.testing.assert_array_equal(view[pose][refl], dp)
