import numpy as np
import pytest

from ocpipe.encoders import slot_metrics as SM


def test_ari_is_one_for_relabelled_partitions_and_near_zero_for_random():
    a = np.repeat([0, 1, 2], 50)
    assert SM.adjusted_rand_index(a, (a + 1) % 3 * 7) == pytest.approx(1.0)
    rng = np.random.default_rng(0)
    assert abs(SM.adjusted_rand_index(rng.integers(0, 3, 3000), rng.integers(0, 3, 3000))) < 0.02


def test_ari_against_a_hand_computed_case():
    # contingency [[2,1,0],[0,1,2]]: index 2, expected 6*3/15 = 1.2, max 0.5*(6+3) = 4.5 -> 0.8/3.3
    ari = SM.adjusted_rand_index(np.array([0, 0, 0, 1, 1, 1]), np.array([0, 0, 1, 1, 2, 2]))
    assert ari == pytest.approx(0.8 / 3.3)


def _one_hot(pred, K):
    return np.moveaxis(np.eye(K)[pred], -1, 1)


def test_perfect_masks_score_perfectly():
    ids = np.zeros((2, 8, 8), int)
    ids[:, 2:4, 2:4] = 1
    ids[:, 5:8, :] = 2
    masks = _one_hot(ids, 4)
    scores = SM.decomposition_scores(masks, ids, ids > 0, {"cube": ids == 1})
    assert scores["fg_ari_mean"] == pytest.approx(1.0) and scores["best_slot_iou_cube"] == pytest.approx(1.0)


def test_merged_objects_lower_the_scores():
    ids = np.zeros((1, 8, 8), int)
    ids[:, 2:4, 2:4] = 1
    ids[:, 5:8, :] = 2
    pred = np.where(ids > 0, 1, 0)  # cube and robot share one slot
    scores = SM.decomposition_scores(_one_hot(pred, 3), ids, ids > 0, {"cube": ids == 1})
    assert scores["fg_ari_mean"] == pytest.approx(0.0) and scores["best_slot_iou_cube"] == pytest.approx(4 / 28)


def test_separation_counts_an_object_whose_slot_also_takes_background_as_separate():
    ids = np.zeros((2, 8, 8), int)
    ids[:, 2:4, 2:4] = 1  # cube
    ids[:, 5:8, :] = 2  # robot
    pred = np.where(ids == 2, 2, 0)
    pred[0][ids[0] == 1] = 1
    pred[0, 0, :] = 1  # image 0: the cube's slot also takes a row of background (IoU 4/12), still its own
    pred[1][ids[1] == 1] = 2  # image 1: cube and robot share a slot
    named = {"cube": ids == 1, "robot": ids == 2}
    s = SM.decomposition_scores(_one_hot(pred, 3), ids, ids > 0, named)
    assert s["separate_cube_robot"] == pytest.approx(0.5)
    assert s["own_slot_cube"] == pytest.approx(0.5) and s["own_slot_robot"] == pytest.approx(0.5)
    assert s["best_slot_iou_cube"] == pytest.approx((4 / 12 + 4 / 28) / 2)


def test_mask_diagnostics_on_disjoint_and_uniform_masks():
    disjoint = _one_hot(np.repeat(np.arange(4), 16).reshape(1, 8, 8), 4)
    d = SM.mask_diagnostics(disjoint)
    assert d["slot_overlap_mean"] == 0 and d["slot_entropy_per_pixel_nats"] == pytest.approx(0, abs=1e-6)
    assert d["slot_activation_mean"] == pytest.approx([0.25] * 4)
    uniform = np.full((1, 4, 8, 8), 0.25)
    u = SM.mask_diagnostics(uniform)
    # A_i.A_j / min(sum A_i, sum A_j) = 64/16 / 16 for four equal masks
    assert u["slot_overlap_mean"] == pytest.approx(0.25) and u["slot_entropy_per_pixel_nats"] == pytest.approx(
        np.log(4)
    )
    assert u["spatial_coherence_mean_abs_diff"] == 0


def test_temporal_diversity_is_mean_pairwise_distance_per_trajectory():
    tokens = np.array([[0.0], [3.0], [0.0], [0.0]])
    # trajectory 0: one pair at distance 3; trajectory 1: identical frames
    assert SM.temporal_diversity(tokens, np.array([0, 0, 1, 1])) == pytest.approx(1.5)
