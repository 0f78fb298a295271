"""Markdown tables of an examination's ``quality.json`` (and an image-only one beside it), for model cards and docs.

    .venv/bin/python scripts/quality_tables.py QUALITY_JSON [IMAGE_ONLY_QUALITY_JSON]
    (e.g. rewards/PegInHole-v1/quality.json rewards/PegInHole-v1/quality_image.json)
    .venv/bin/python scripts/quality_tables.py --check CHECK_REWARD_JSON
    (``check-reward``'s report, e.g. rewards/PegInHole-v1/check_reward.json)

Prints the measures against their targets, the held positions, and with a second file the
two checkpoints side by side. The numbers are read, never typed.
"""

from __future__ import annotations

import json
import sys


def _f(x, digits=3) -> str:
    return "n/a" if x is None else f"{x:.{digits}f}"


def measures(q: dict) -> list:
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
    """The markdown."""
    out = ["| measure | value | target |", "| --- | --- | --- |"]
    out += [f"| {a} | {b} | {c} |" for a, b, c in measures(q)]
    out += ["", "| where the tip is held | mean | std |", "| --- | --- | --- |"]
    for k, v in q.get("held_positions", {}).items():
        out.append(f"| {k} | {_f(v['mean'])} | {_f(v['std'])} |")
    if image is not None:
        out += ["", "| measure | images + F/T | images only |", "| --- | --- | --- |"]
        for (a, b, _), (_, c, _) in zip(measures(q), measures(image)):
            out.append(f"| {a} | {b} | {c} |")
        for k, v in q.get("held_positions", {}).items():
            w = image.get("held_positions", {}).get(k, {})
            out.append(f"| held {k}: mean | {_f(v['mean'])} | {_f(w.get('mean'))} |")
    return "\n".join(out)


def main() -> None:
    """Command line."""
    if sys.argv[1:2] == ["--check"] and len(sys.argv) == 3:
        from drem_maniskill.pipeline.check_reward import markdown_table

        print(markdown_table(json.load(open(sys.argv[2]))))
        return
    files = [json.load(open(p)) for p in sys.argv[1:3]]
    if not files:
        sys.exit(__doc__)
    print(tables(files[0], files[1] if len(files) > 1 else None))


if __name__ == "__main__":
    main()
