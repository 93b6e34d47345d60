"""The reference data load, and the dam break's front measure reproduces the published spreads."""

import numpy as np
import pytest

from fempm import references


def test_interfoam_meshes_differ_as_published():
    """data/reference/README: interFoam 40² and 80² differ from 160² by 2.0 % and 1.1 % (0.3 <= T <= 3)."""
    finest = references.interfoam_front(160)
    assert references.front_difference(references.interfoam_front(40), finest) == pytest.approx(0.0206, abs=5e-4)
    assert references.front_difference(references.interfoam_front(80), finest) == pytest.approx(0.0119, abs=5e-4)
    assert references.front_difference(finest, finest) == 0.0


def test_front_difference_is_relative_rms_at_reference_times():
    reference = np.array([[0.0, 1.0], [0.5, 2.0], [1.0, 4.0], [2.0, 8.0]])
    front = np.array([[0.0, 1.0], [2.0, 8.8]])  # Z = 1 + 3.9 T: 2.95, 4.9 at T = 0.5, 1 (beyond 2: left out)
    expected = np.sqrt(np.mean([(2.95 / 2 - 1) ** 2, (4.9 / 4 - 1) ** 2, (8.8 / 8 - 1) ** 2]))
    assert references.front_difference(front, reference, T_min=0.3, T_max=3.0) == pytest.approx(expected, rel=1e-14)
    with pytest.raises(ValueError, match="reaches no reference time"):
        references.front_difference(front[:1], reference)


def test_probes_and_experiments_load():
    t, probes = references.interfoam_probes(160)
    assert len(t) == len(probes["right_y0.005"]) > 1000
    assert {"right_y0.005", "left_y0.005", "floor_x0.292"} <= set(probes)
    experiment = references.dambreak_front("koshizuka_oka_1996_experiment")
    assert experiment[0].tolist() == [0.0, 1.0] and experiment.shape[1] == 2
