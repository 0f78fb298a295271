"""The examination's probes: one table, each probe a named place with what it tests."""

from drem_maniskill.evaluate.probes import (
    FACE_PUSHED, FLOOR_POSITION, HOLD_POSITIONS, PROBES, SIDE_POSITION, SIDE_PUSHED, TURN, TURNED_HOVER, UPRIGHT_HOVER,
)


def test_every_probe_is_named_once_and_says_in_one_line_what_it_tests():
    names = [p.name for p in PROBES]
    assert len(set(names)) == len(names) and "inserted" not in names  # "inserted" is the expert's, read beside them
    assert all(p.tests and "\n" not in p.tests for p in PROBES)


def test_the_fixed_places_come_first_and_the_rest_in_the_quality_files_order():
    assert list(HOLD_POSITIONS) == [p.name for p in PROBES][:len(HOLD_POSITIONS)]
    assert [p.name for p in PROBES][len(HOLD_POSITIONS):] == [FLOOR_POSITION, SIDE_POSITION, SIDE_PUSHED, FACE_PUSHED,
                                                             TURNED_HOVER, UPRIGHT_HOVER]
    assert HOLD_POSITIONS["pressed 3 mm beside"] == (0.003, 0.0, -0.002)
    # The colour spread is read over the fixed places above the face: seven of them.
    assert sum(at[2] > 0 for at in HOLD_POSITIONS.values()) == 7
    turned = {p.name: p.turn for p in PROBES if p.turn is not None}
    assert turned == {TURNED_HOVER: TURN}
    assert {p.name for p in PROBES if p.via is not None} == {SIDE_POSITION, SIDE_PUSHED}


def test_the_reward_read_only_at_a_holds_end_is_the_last_reward_of_the_same_hold_paid_every_step():
    """The hold runs without its per-step reward (nothing renders): its end pays what the same episode's last step
    pays with the reward on, images and F/T history alike; the env keeps its reward mode. Each in a new env: an
    episode after another in the same env does not replay it exactly (the controller keeps its state)."""
    import gymnasium as gym

    import drem_maniskill  # noqa: F401
    from drem_maniskill.evaluate.probes import end_reward, hold_targets
    from drem_maniskill.experts import rollout
    from drem_maniskill.experts.scripted import HoldPolicy

    def hold(run):
        env = gym.make("PegInHole-v1", obs_mode="state_dict", reward_mode="drem")
        try:
            target = hold_targets(env)["pressed 3 mm beside"]  # in contact: the F/T history is not zero
            out = run(env, HoldPolicy(env, target))
            return out, env.unwrapped.reward_mode, float(env.unwrapped.ft.buffer.abs().max())
        finally:
            env.close()

    paid, _, _ = hold(lambda env, policy: rollout(env, policy, 3, 12, stop_on_success=False))
    (read, ep), mode, force = hold(lambda env, policy: end_reward(env, policy, 3, 12))
    assert mode == "drem" and force > 0 and ep.length == paid.length == 12
    assert set(ep.rewards) == {0.0} and len(set(paid.rewards)) > 1  # the hold itself was not paid
    assert read == paid.rewards[-1]


def test_a_reward_that_is_not_drem_is_paid_every_step_and_the_last_one_read():
    """``end_reward`` on another reward (here the task's normalized_dense): every step paid, the last one returned."""
    import gymnasium as gym

    import drem_maniskill  # noqa: F401
    from drem_maniskill.evaluate.probes import end_reward, hold_targets
    from drem_maniskill.experts.scripted import HoldPolicy

    env = gym.make("PegInHole-v1", obs_mode="state_dict", reward_mode="normalized_dense")
    try:
        read, ep = end_reward(env, HoldPolicy(env, hold_targets(env)["4 mm above"]), 3, 6)
    finally:
        env.close()
    assert ep.length == 6 and len(set(ep.rewards)) > 1 and read == ep.rewards[-1]
