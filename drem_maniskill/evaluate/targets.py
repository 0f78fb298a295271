"""The quality targets: an examination's ``quality.json`` against what a reward should reach, as model cards show it.

``tables(quality)`` is the markdown of a model card's measures (every number read from the file, never typed):
the measures with their targets, the probes held, and with a second file (an image-only checkpoint) the two side
by side. ``scripts/quality_tables.py`` prints it.
"""

from __future__ import annotations


def _f(x, digits=3) -> str:
    return "n/a" if x is None else f"{x:.{digits}f}"


def measure_rows(q: dict) -> list:
    """``(name, value, target)`` rows of one ``quality.json``."""
    plateau, loss = q.get("contact_plateau") or {}, q.get("search_fail_first_contact_loss") or {}
    rates = q.get("success_rate", {})
    # The expert-and-noisy-expert AUROC exists where the examination ran a noisy expert (ManiSkill's own tasks).
    experts_auroc = [("AUROC of the final-step reward over the expert and the noisy expert only",
                      _f(q["final_reward_auroc_expert_noisy"]), ">= 0.9")] \
        if q.get("final_reward_auroc_expert_noisy") is not None else []
    # The scene swap exists in examinations that ran it (docs/drem.md, "Examination").
    swap = [("the expert's end with every other body back at its start, over the end (near 1: the reward reads the "
             "robot)", _f(q["robot_only_over_expert"]), "well below 1")] \
        if q.get("robot_only_over_expert") is not None else []
    return [
        ("value-order Spearman (reward vs time step, expert episodes)", _f(q["value_order_spearman"]), ">= 0.95"),
        ("AUROC of the final-step reward, success vs failure", _f(q["final_reward_auroc"]), ">= 0.98"),
        *experts_auroc,
        ("Random policy mean reward", _f(q["random_mean_reward"]), "<= 0.1"),
        *swap,
        (f"contact plateau: Align Success from first contact to insertion, over Direct Success's final "
         f"({plateau.get('episodes')} episodes)",
         f"{_f(plateau.get('fraction'))} "
         f"({_f(plateau.get('mean_reward'))} / {_f(plateau.get('direct_success_final'))})", "<= 0.6"),
        (f"Search Fail 1 / 3 steps after it first loses contact ({loss.get('episodes_with_loss')} episodes)",
         f"{_f(loss.get('after_1'))} / {_f(loss.get('after_3'))}", "<= 0.1 at 3"),
        ("colour spread: the largest standard deviation over episodes at a held position above the opening",
         _f((q.get("colour_spread") or {}).get("max_std")), "<= 0.05"),
        ("finished, held insertion: standard deviation over episodes", _f(q.get("inserted_reward_std")), "<= 0.1"),
        ("pressed on the floor 75 mm beside the socket, over a finished insertion (the trap SAC found)",
         _f(q.get("floor_beside_over_inserted")), "well below 1"),
        ("pressed on the face 3 mm beside the opening, over hovering 4 mm above it 4 mm off (below 1: touching down "
         "off the axis loses reward)", _f(q.get("face_over_hover")), ""),
        ("examination success rates", ", ".join(f"{k} {v:.0%}" for k, v in rates.items()), ""),
        ("Spearman with the task's `normalized_dense`, all rollouts / expert rollouts",
         f"{_f(q.get('spearman_with_normalized_dense'))} / {_f(q.get('spearman_with_normalized_dense_expert'))}", ""),
    ]


def tables(q: dict, image: dict | None = None) -> str:
    """The markdown of ``q``'s measures and probes; with ``image``, the two checkpoints side by side after them."""
    out = ["| measure | value | target |", "| --- | --- | --- |"]
    out += [f"| {a} | {b} | {c} |" for a, b, c in measure_rows(q)]
    out += ["", "| where the tip is held | mean | std |", "| --- | --- | --- |"]
    for k, v in q.get("held_positions", {}).items():
        out.append(f"| {k} | {_f(v['mean'])} | {_f(v['std'])} |")
    if image is not None:
        out += ["", "| measure | images + F/T | images only |", "| --- | --- | --- |"]
        for (a, b, _), (_, c, _) in zip(measure_rows(q), measure_rows(image)):
            out.append(f"| {a} | {b} | {c} |")
        for k, v in q.get("held_positions", {}).items():
            w = image.get("held_positions", {}).get(k, {})
            out.append(f"| held {k}: mean | {_f(v['mean'])} | {_f(w.get('mean'))} |")
    return "\n".join(out)
