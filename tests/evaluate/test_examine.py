"""The examination's measures."""

import numpy as np
import pytest


def test_pooled_spearman_uses_every_step_and_skips_constant_signals():
    from drem_maniskill.evaluate.quality import _pooled_spearman

    eps = [dict(rewards=[0.1, 0.2, 0.3], normalized_dense=[1.0, 2.0, 4.0]),
           dict(rewards=[0.5, 0.4], normalized_dense=[5.0, 4.5])]
    assert _pooled_spearman(eps, "normalized_dense") == pytest.approx(1.0)
    eps[1]["normalized_dense"] = [0.0, 9.0]  # one pair now runs against the rest
    assert _pooled_spearman(eps, "normalized_dense") < 1.0
    assert _pooled_spearman([dict(rewards=[1, 2, 3], insertion_depth=[0, 0, 0])], "insertion_depth") is None
    assert _pooled_spearman([dict(rewards=[1, 2, 3])], "insertion_depth") is None


def test_contact_plateau_is_align_successs_reward_between_contact_and_insertion_over_direct_success():
    from drem_maniskill.evaluate.measures import contact_plateau

    # Contact (force > 3 N) from step 2; the tip goes below 1 mm at step 5.
    ep = dict(rewards=[0.1, 0.2, 0.5, 0.6, 0.7, 0.9, 1.0], force=[0, 0, 5, 6, 4, 2, 1],
              insertion_depth=[-0.01, -0.005, 0.0, 0.0, 0.0005, 0.002, 0.01])
    untouched = dict(rewards=[0.3, 0.3], force=[0, 0], insertion_depth=[-0.01, -0.01])
    out = contact_plateau([ep, untouched], direct_final=0.9)
    assert out["episodes"] == 1 and out["mean_reward"] == pytest.approx(0.6)
    assert out["fraction"] == pytest.approx(0.6 / 0.9)
    assert contact_plateau([untouched], 0.9)["fraction"] is None
    assert "on_face" not in out  # no radial offsets recorded: no split


def test_contact_plateau_splits_its_steps_into_the_face_and_the_opening():
    from drem_maniskill.evaluate.measures import contact_plateau

    # Contact from step 1; on the face 3 mm and 2 mm off, then slid to the mouth (0.4 mm off, 0.3 mm in).
    ep = dict(rewards=[0.2, 0.5, 0.7, 0.9, 1.0], force=[0, 6, 6, 2, 1],
              insertion_depth=[-0.01, 0.0, 0.0, 0.0003, 0.005], radial_offset=[0.003, 0.003, 0.002, 0.0004, 0.0002])
    out = contact_plateau([ep], direct_final=1.0)
    assert out["mean_reward"] == pytest.approx(0.7)
    assert out["on_face"] == dict(steps=2, mean_reward=pytest.approx(0.6), fraction=pytest.approx(0.6))
    assert out["at_opening"] == dict(steps=1, mean_reward=pytest.approx(0.9), fraction=pytest.approx(0.9))


def test_first_contact_loss_reads_the_reward_one_and_three_steps_after():
    from drem_maniskill.evaluate.measures import first_contact_loss

    ep = dict(rewards=[0.1, 0.5, 0.6, 0.2, 0.15, 0.05, 0.4, 0.0], force=[0, 4, 5, 0.5, 0.2, 0.1, 6, 0.1])
    assert first_contact_loss(ep) == dict(step=3, before=0.6, after_1=0.2, after_3=0.05)  # the first loss, not the last
    assert first_contact_loss(dict(rewards=[0.1, 0.2], force=[0, 0])) is None
    from drem_maniskill.evaluate.measures import contact_loss_drop

    assert contact_loss_drop(ep) == (0.4, 0.0)  # the drop at the last loss


def test_face_lead_is_the_rise_towards_the_opening_within_each_episode_on_the_face_only():
    from drem_maniskill.evaluate.measures import face_lead

    rng = np.random.default_rng(0)
    offsets = np.array([0.0, 0.3, -0.3, 0.1, -0.1] * 2)  # per episode: colours and placement shift the whole face

    def rows(reward_at, shift=0.0):
        out = []
        for mm in (1, 2, 3, 4, 6):
            noise = 0.01 * rng.standard_normal(10)
            out.append(dict(tip_mm=[mm, 0.0, 0.0], r=dict(values=list(reward_at(mm) + shift * offsets + noise))))
        # Inserted (below the face) and far off the axis: not on the face near the opening.
        out.append(dict(tip_mm=[0.0, 0.0, -2.0], r=dict(values=[5.0] * 10)))
        out.append(dict(tip_mm=[0.0, 12.0, 0.0], r=dict(values=[-5.0] * 10)))
        return out

    leading = face_lead(rows(lambda mm: 0.8 - 0.02 * mm), "r", start=0.0, inserted=1.0)
    flat = face_lead(rows(lambda mm: 0.8), "r", start=0.0, inserted=1.0)
    assert leading["positions"] == 5 and leading["slope_per_mm"] == pytest.approx(-0.02, abs=0.005)
    assert leading["lead"] > 1.5 and leading["order"] > 0.8
    assert abs(flat["lead"]) < 0.75 and abs(flat["order"]) < 0.4
    assert flat["to_go"] == pytest.approx(0.2, abs=0.01)  # (1 - 0.8) / (1 - 0)
    # An offset per episode moves the whole face: it is reported apart and does not hide the lead.
    shifted = face_lead(rows(lambda mm: 0.8 - 0.02 * mm, shift=1.0), "r", start=0.0, inserted=1.0)
    assert shifted["lead"] > 1.5 and shifted["order"] > 0.8
    assert shifted["between_episodes"] > 0.1 > leading["between_episodes"]
    # Another reward's scale and sign: the same fraction still to go.
    assert face_lead(rows(lambda mm: 0.8), "r", start=-2.0, inserted=1.0)["to_go"] == pytest.approx(0.2 / 3, abs=0.01)
    assert face_lead(rows(lambda mm: 0.8)[-2:], "r", 0.0, 1.0)["lead"] is None


def test_the_experts_auroc_leaves_random_actions_out():
    from drem_maniskill.evaluate.measures import auroc
    from drem_maniskill.evaluate.quality import _split_finals

    def ep(final, success):
        return dict(rewards=[0.0, final], success=success)

    # Random actions fail far from the goal and are easy to tell apart; the noisy expert's failure at 0.9 is not.
    curves = dict(direct_success=[ep(0.8, True), ep(0.95, True)], noisy_expert=[ep(0.9, False), ep(0.85, True)],
                  random=[ep(0.1, False), ep(0.0, False)])
    assert _split_finals(curves, ("direct_success", "noisy_expert")) == ([0.8, 0.95, 0.85], [0.9])
    assert auroc(*_split_finals(curves, ("direct_success", "noisy_expert"))) == pytest.approx(1 / 3)
    assert auroc(*_split_finals(curves, tuple(curves))) == pytest.approx(7 / 9)



def test_quality_holds_every_measure_in_the_files_order():
    from drem_maniskill.evaluate.probes import HOLD_POSITIONS
    from drem_maniskill.evaluate.quality import quality

    def ep(rewards, success, **extra):
        return dict(rewards=rewards, success=success, force=[0.0] * len(rewards), normalized_dense=[],
                    insertion_depth=[], radial_offset=[], **extra)

    expert = [ep([0.1, 0.4, 0.9], True), ep([0.2, 0.3, 0.5], False)]
    curves = dict(direct_success=[ep([0.2, 0.9], True)], random=[ep([0.0, 0.1], False)])
    held = {k: dict(rewards=[0.3], mean=0.3, std=0.01 * i, reached_error_mm=0.1)
            for i, k in enumerate(HOLD_POSITIONS)}
    held["inserted"] = dict(rewards=[0.9], mean=0.9, std=0.0, reached_error_mm=None)
    swaps = [dict(end=1.0, robot_at_end=0.5, objects_at_end=0.9)]
    q = quality("PegInHole-v1", "drem.pt", range(2), expert, curves, held, swaps)
    assert list(q) == [
        "env_id", "checkpoint", "seeds", "value_order_spearman", "value_order_spearman_per_episode",
        "expert_success_rate", "final_reward_auroc", "final_reward_auroc_expert_noisy", "random_mean_reward",
        "robot_only_over_expert", "objects_only_over_expert", "search_fail_contact_loss", "contact_plateau",
        "search_fail_first_contact_loss", "colour_spread", "held_positions", "inserted_reward_std",
        "floor_beside_over_inserted", "side_over_inserted", "side_pushed_over_inserted", "face_pushed_over_inserted",
        "face_over_hover", "turned_over_upright", "turned_over_inserted", "mouth_off_axis_over_on_axis", "success_rate",
        "spearman_with_normalized_dense", "spearman_with_insertion_depth", "spearman_with_normalized_dense_expert",
        "dense_curves", "curves", "expert_curves"]
    assert q["value_order_spearman"] == pytest.approx(1.0) and q["expert_success_rate"] == 0.5
    assert q["final_reward_auroc"] == 1.0 and q["random_mean_reward"] == pytest.approx(0.05)
    assert q["robot_only_over_expert"] == 0.5 and q["face_over_hover"] == pytest.approx(1.0)
    assert q["mouth_off_axis_over_on_axis"] == pytest.approx(1.0)
    assert q["floor_beside_over_inserted"] is None  # not held here
    # Over the fixed places above the face only: the two below it ("pressed 3 mm beside", "25 mm down") do not count.
    assert q["colour_spread"]["max_std"] == pytest.approx(0.06)
