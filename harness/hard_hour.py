"""make bench's harder hour (issue 57, item 6): the live stack on a script beside the live
hour's (harness/live_hour.py), in parts, each scored against the same targets.

The parts (:func:`hard_script`, seeded; the board drifts as ``hard_hour.drift_offset_pf``
says, a real skin's size, through all of them):

- ``light_edges``: the plan's lightest force on every edge and corner node (a two-contact
  scene: every pair of edge nodes), at every stretch the scene was trained on;
- ``held_through_stretch``: presses held while the stretch changes half-way (none on a
  scene trained at one stretch);
- ``taps``: short presses anywhere on the plan;
- ``long_presses``: light edge presses of minutes, the first at the largest stretch,
  each followed by minutes untouched;
- ``untouched``: untouched at the largest stretch, last.

Each part is scored on its own frames (:func:`score_hard`): phantom contacts on its
untouched frames, the longest phantom (a run of contact on untouched frames, from a
release's first frame on), missed contacts on its pressed frames, location and force of
the detected frames against the conditions-CV scores' spread, and its long presses held;
each against ``hard_hour.targets`` (:func:`verdicts`), met or missed. A two-contact
stack reports two contacts on every frame (issue 57, item 3): its "contact" is that it
reports one, and its location the pair (as :mod:`eskin.evaluation.pairs` scores it).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from eskin.data.plan import ScenePlan
from eskin.kinds import ONE_CONTACT, TWO_CONTACTS
from harness.live_hour import GRACE_MS, LIGHT_EDGES, Press, Step, says_contact, scene_presses

PARTS = ("light_edges", "held_through_stretch", "taps", "long_presses", "untouched")
# The parts whose presses are all the plan's lightest on edge and corner nodes: their
# location and force are set beside the batch's on such presses, where it has them
# (harness.live_hour.light_edge_rows), not beside the average press's.
LIGHT_EDGE_PARTS = ("light_edges", "long_presses")
WHOLE = "whole"  # the whole script, every part's frames
TITLES = {"light_edges": "light edge and corner presses",
          "held_through_stretch": "presses held through a stretch change",
          "taps": "taps", "long_presses": "long presses, and after",
          "untouched": "untouched at the largest stretch", WHOLE: "the whole script"}
# The targets, each: what it judges, the score it reads (None: judged otherwise)
TARGETS = ("phantom", "longest_phantom", "missed", "location", "force", "held")


def edge_presses(plan: ScenePlan) -> list[Press]:
    """The plan's presses at its lightest force whose every contact is on the skin's edge
    (its first or last row or column of nodes)."""
    presses = scene_presses(plan)
    lightest = min(f for press in presses for _, _, f in press)
    xs, ys = zip(*plan.skin.nodes(), strict=True)

    def on_edge(x, y):
        return x in (min(xs), max(xs)) or y in (min(ys), max(ys))

    return [p for p in presses
            if all(f == lightest and on_edge(x, y) for x, y, f in p)]


def trained_stretches_mm(plan: ScenePlan, rest_length_mm: float) -> list[float]:
    """The stretches (mm of extension) the scene was trained on, smallest first."""
    return sorted(round((float(s) - 1.0) * rest_length_mm, 3)
                  for s in {c.stretch for c in plan.conditions})


def hard_script(settings, plan: ScenePlan, rest_length_mm: float) -> tuple[list[Step], int]:
    """The harder hour's steps, each labelled with its part, and its end (ms of board
    time). ``settings``: bench/params.yaml's ``hard_hour``."""
    rng = np.random.default_rng(settings.seed)
    gap = int(settings.untouched_s * 1000)
    trained = trained_stretches_mm(plan, rest_length_mm)
    presses, edges = scene_presses(plan), edge_presses(plan)
    # The board starts at rest, untouched: live's tare is taken there.
    steps = [Step(0, (), 0.0, "untouched", part=PARTS[0])]
    t, stretch = gap, 0.0

    def change_stretch(mm: float, part: str) -> None:  # then untouched for a gap
        nonlocal t, stretch
        if mm != stretch:
            steps.append(Step(t, (), mm, "stretch", part=part))
            stretch, t = mm, t + gap

    def hold(press: Press, mm: float, kind: str, part: str, held_ms: int) -> None:
        nonlocal t, stretch
        steps.append(Step(t, press, mm, kind, part=part))
        stretch, t = mm, t + held_ms

    def release(part: str, untouched_ms: int = gap) -> None:
        nonlocal t
        steps.append(Step(t, (), stretch, "untouched", part=part))
        t += untouched_ms

    def pick(choices: list[Press]) -> Press:
        return choices[int(rng.integers(len(choices)))]

    def pick_from(values: list[float]) -> float:
        return values[int(rng.integers(len(values)))]

    for mm in trained:
        change_stretch(mm, "light_edges")
        for i in rng.permutation(len(edges)):
            hold(edges[i], mm, "press", "light_edges", int(settings.light_press_s * 1000))
            release("light_edges")
    if len(trained) > 1:
        whole = int(settings.held_press_s * 1000)
        for _ in range(settings.held_presses):
            press = pick(presses)
            hold(press, stretch, "press", "held_through_stretch", whole // 2)
            other = [mm for mm in trained if mm != stretch]
            hold(press, pick_from(other), "press", "held_through_stretch", whole - whole // 2)
            release("held_through_stretch")
    for _ in range(settings.taps):
        hold(pick(presses), stretch, "tap", "taps", int(settings.tap_ms))
        release("taps")
    for i, minutes in enumerate(settings.long_presses_min):
        change_stretch(trained[::-1][min(i, len(trained) - 1)], "long_presses")
        hold(pick(edges), stretch, "long", "long_presses", int(minutes * 60_000))
        release("long_presses", int(settings.after_long_s * 1000))
    change_stretch(trained[-1], "untouched")
    release("untouched", int(settings.untouched_min * 60_000))
    return steps, t


# ---------------------------------------------------------------- scoring


def reported(frame: pd.DataFrame) -> pd.Series:
    """Whether live reported a contact on each frame: its hysteresis' verdict, or, for a
    stack that counts none (two contacts on the paper's plan), that it placed one."""
    if says_contact(frame):
        return frame["contact"].fillna(False).astype(bool)
    return frame[TWO_CONTACTS.node_columns[0]].notna()


def phantom_runs(frame: pd.DataFrame, contact: pd.Series) -> pd.DataFrame:
    """Every run of consecutive untouched frames live reported contact on, within a part
    (one carried into the next part is two, each its part's): its part, start and length
    in seconds (one frame period per frame)."""
    period = float(frame.attrs.get("frame_period_ms", 12.0))
    phantom = (~frame["pressed"]) & contact
    run = (phantom.ne(phantom.shift()) | frame["part"].ne(frame["part"].shift())).cumsum()[
        phantom]
    if run.empty:
        return pd.DataFrame(columns=["part", "t_ms", "seconds"])
    grouped = frame.loc[run.index].groupby(run.to_numpy())
    return pd.DataFrame({"part": grouped["part"].first(), "t_ms": grouped["t_ms"].first(),
                         "seconds": (grouped["t_ms"].last() - grouped["t_ms"].first()
                                     + period) / 1000})


def part_scores(rows: pd.DataFrame, contact: pd.Series, runs: pd.DataFrame,
                pairs: bool) -> dict[str, Any]:
    """One part's scores (``rows``: its frames; ``runs``: its phantoms)."""
    untouched = (~rows["pressed"]) & (rows["since_ms"] >= GRACE_MS)
    pressed = rows["pressed"] & (rows["since_ms"] >= GRACE_MS)
    press_run = rows["pressed"].ne(rows["pressed"].shift()).cumsum()
    seen = (pressed & contact).groupby(press_run[rows["pressed"]]).any()
    long = pressed & (rows["kind"] == "long")
    found = rows[pressed & contact]
    out: dict[str, Any] = {
        "frames": len(rows), "untouched_frames": int(untouched.sum()),
        "pressed_frames": int(pressed.sum()), "located_frames": len(found),
        "presses": int(len(seen)), "presses_never_seen": int((~seen).sum()),
        "phantom_share": _share(contact[untouched]),
        "longest_phantom_s": (round(float(runs["seconds"].max()), 3) if len(runs) else 0.0)
        if (~rows["pressed"]).any() else None,
        "missed_share": _share(~contact[pressed]),
        "held_share": _share(contact[long]) if long.any() else None,
    }
    if pairs:
        out.update(_pair_scores(found))
    else:
        out.update({
            "x_accuracy": _share(found["x"] == found["true_x"]) if len(found) else None,
            "y_accuracy": _share(found["y"] == found["true_y"]) if len(found) else None,
            "force_mae_n": round(float((found["force"] - found["true_force"]).abs().mean()), 4)
            if len(found) else None})
    return out


def _pair_scores(found: pd.DataFrame) -> dict[str, Any]:
    from eskin.evaluation.pairs import CONTACTS, pair_outcomes, pair_scores

    if found.empty:
        return {"pair_accuracy": None, "force_mae_n": None}
    # a contact a counting stack does not place (it counted fewer) is node 0, 0 N: wrong
    named = pd.DataFrame({
        **{f"{a}{i}_{side}": found[f"{'true_' if side == 'true' else ''}{a}{i}"].astype(float)
           for a in ("x", "y", "force") for i in CONTACTS for side in ("true", "pred")}}
        ).fillna(0.0)
    scores = pair_scores(pair_outcomes(named))
    return {"pair_accuracy": round(float(scores["pair_accuracy"]), 5),
            "force_mae_n": round(float(scores["force_mae"]), 4)}


def verdicts(scores: dict[str, Any], batch_cv: dict[str, Any], targets) -> dict[str, bool]:
    """Each target of a part, met (True) or missed (False); a target its part has no frames
    for (or no conditions-CV score to set beside) is left out."""
    k = float(targets.cv_sds)

    def at_least(live, name):  # within the spread or better: no more than k SDs below
        mean, sd = batch_cv[name]
        return live >= mean - k * sd

    out: dict[str, bool] = {}
    if scores["phantom_share"] is not None:
        out["phantom"] = scores["phantom_share"] <= targets.phantom_share
    if scores["longest_phantom_s"] is not None:
        out["longest_phantom"] = scores["longest_phantom_s"] <= targets.phantom_after_release_s
    if scores["missed_share"] is not None:
        out["missed"] = scores["missed_share"] <= targets.missed_share
    if "pair_accuracy" in scores:
        if scores["pair_accuracy"] is not None and "pair_accuracy" in batch_cv:
            out["location"] = at_least(scores["pair_accuracy"], "pair_accuracy")
    elif scores["x_accuracy"] is not None and {"x_accuracy", "y_accuracy"} <= set(batch_cv):
        out["location"] = (at_least(scores["x_accuracy"], "x_accuracy")
                           and at_least(scores["y_accuracy"], "y_accuracy"))
    if scores["force_mae_n"] is not None and "force_mae" in batch_cv:
        mean, sd = batch_cv["force_mae"]
        out["force"] = scores["force_mae_n"] <= mean + k * sd
    if scores["held_share"] is not None:
        out["held"] = scores["held_share"] >= targets.held_share
    return out


def part_reference(part: str, batch_cv: dict[str, Any]) -> dict[str, Any]:
    """The batch scores a part's location and force are set beside: a light edge part's
    class (:data:`LIGHT_EDGE_PARTS`), where the scene has its scores; else every press's."""
    return batch_cv.get(LIGHT_EDGES, batch_cv) if part in LIGHT_EDGE_PARTS else batch_cv


def mixed_reference(parts: dict[str, dict[str, Any]],
                    batch_cv: dict[str, Any]) -> dict[str, Any]:
    """The whole script's: each part's reference (mean and fold SD) weighted by the frames
    it located, so the whole is set beside the batch on the same mix of presses (most of
    the whole's frames are the long presses'). Every press's where no part located any."""
    weights = {part: scores["located_frames"] for part, scores in parts.items()
               if scores["located_frames"]}
    total = sum(weights.values())
    mixed = dict(batch_cv)
    for name in ("x_accuracy", "y_accuracy", "force_mae", "pair_accuracy"):
        references = [part_reference(part, batch_cv).get(name) for part in weights]
        if total and all(r is not None for r in references):
            mixed[name] = [round(sum(w * r[i] for w, r in zip(weights.values(), references,
                                                                strict=True)) / total, 4)
                           for i in (0, 1)]
    return mixed


def score_hard(frame: pd.DataFrame, batch_cv: dict[str, Any], targets) -> dict[str, Any]:
    """Every part's scores and verdicts, and the whole script's (``frame``: what
    :func:`harness.live_hour.run` returns for :func:`hard_script`)."""
    pairs = TWO_CONTACTS.node_columns[0] in frame
    contact = reported(frame)
    runs = phantom_runs(frame, contact)
    parts: dict[str, Any] = {}
    for part in [*[p for p in PARTS if (frame["part"] == p).any()], WHOLE]:
        rows = frame if part == WHOLE else frame[frame["part"] == part]
        scores = part_scores(rows, contact.loc[rows.index],
                             runs if part == WHOLE else runs[runs["part"] == part], pairs)
        reference = mixed_reference(parts, batch_cv) if part == WHOLE \
            else part_reference(part, batch_cv)
        judged = verdicts(scores, reference, targets)
        parts[part] = {**scores, "verdicts": judged, "met": all(judged.values())}
    return {"frames": len(frame),
            "hours": round(float(frame["t_ms"].max() - frame["t_ms"].min()) / 3.6e6, 3),
            "two_contacts": pairs, "parts": parts,
            # a two-contact stack counts where its scene recorded fewer (contact_counts)
            **({"counts_contacts": says_contact(frame)} if pairs else {}),
            "phantoms_longer_than_target": int((runs["seconds"]
                                                > targets.phantom_after_release_s).sum()),
            "latency_ms_median": round(  # one frame through the stack run() ran
                frame.attrs["single_frame_seconds"][0] * 1000, 3),
            "batch_cv": batch_cv,
            "targets": targets.model_dump()}


def _share(values) -> float | None:
    values = np.asarray(values, dtype=bool)
    return round(float(values.mean()), 5) if len(values) else None


# ---------------------------------------------------------------- the table


def render(scene: str, result: dict[str, Any]) -> str:
    """The markdown table (reports/hard_hour/<scene>.md): a row per part, each target's
    score (a missed one in bold), and the part's verdict."""
    t, cv, pairs = result["targets"], result["batch_cv"], result["two_contacts"]
    k = t["cv_sds"]
    sds = f"{k:g} fold SD{'s' if k != 1 else ''}"
    location = "pairs right" if pairs else "x, y right"
    header = ["part", "presses (never seen)", "phantom", "longest phantom", "missed",
              location, "force MAE", "long presses held", "verdict"]
    target_row = ["target", "", f"≤ {100 * t['phantom_share']:g} %",
                  f"≤ {t['phantom_after_release_s']:g} s", f"≤ {100 * t['missed_share']:g} %",
                  f"≥ CV − {sds}", f"≤ CV + {sds}", f"{100 * t['held_share']:g} %", ""]
    lines = [f"# Harder hour: {scene}, {result['hours']} h of board time, "
             f"{result['frames']} frames", "",
             "| " + " | ".join(header) + " |", "|" + "---|" * len(header),
             "| " + " | ".join(target_row) + " |"]
    for part, s in result["parts"].items():
        judged = s["verdicts"]

        def cell(name, text, judged=judged):
            return text if judged.get(name, True) else f"**{text}**"

        if pairs:
            where = _pct(s["pair_accuracy"])
        else:
            where = "–" if s["x_accuracy"] is None else \
                f"{_pct(s['x_accuracy'])}, {_pct(s['y_accuracy'])}"
        missed = [name.replace("_", " ") for name, ok in judged.items() if not ok]
        row = [TITLES[part],
               f"{s['presses']} ({s['presses_never_seen']})" if s["presses"] else "–",
               cell("phantom", _pct(s["phantom_share"])),
               cell("longest_phantom", "–" if s["longest_phantom_s"] is None
                    else f"{s['longest_phantom_s']:g} s"),
               cell("missed", _pct(s["missed_share"])),
               cell("location", where),
               cell("force", "–" if s["force_mae_n"] is None else f"{s['force_mae_n']:.3f} N"),
               cell("held", _pct(s["held_share"])),
               "met" if s["met"] else "MISSED: " + ", ".join(missed)]
        lines.append("| " + " | ".join(row) + " |")
    if pairs:
        spread = [f"pairs right {_spread(cv, 'pair_accuracy', 100, ' %')}"]
    else:
        spread = [f"x {_spread(cv, 'x_accuracy', 100, ' %')}",
                  f"y {_spread(cv, 'y_accuracy', 100, ' %')}"]
    spread.append(f"force MAE{'' if pairs else ' on pressed rows'} "
                  f"{_spread(cv, 'force_mae', 1, ' N')}")
    if LIGHT_EDGES in cv:
        light = cv[LIGHT_EDGES]
        where = [f"pairs right {_spread(light, 'pair_accuracy', 100, ' %')}"] if pairs else [
            f"x {_spread(light, 'x_accuracy', 100, ' %')}",
            f"y {_spread(light, 'y_accuracy', 100, ' %')}"]
        spread.append("and on the lightest presses on edge and corner nodes, which the "
                      "light edge and long press parts are set beside (the whole script: "
                      "each part's, weighted by the frames it located): "
                      + ", ".join(where)
                      + f", force MAE {_spread(light, 'force_mae', 1, ' N')}")
    lines += ["", "Conditions CV (mean ± fold SD): " + ", ".join(spread) + ". "
              f"Frames scored: a press's first {GRACE_MS} ms, and a release's, are not "
              "(the longest phantom counts from the release's first frame). "
              f"The {result.get('stack', 'onnx')} stack's latency, one frame, median: "
              f"{result['latency_ms_median']} ms."]
    if pairs and result.get("counts_contacts"):
        lines += ["", "Two contacts: the stack counts them (its scene was recorded with "
                  "contact_counts), and a frame it counts none on is untouched."]
    elif pairs:
        lines += ["", "Two contacts: the stack reports two contacts on every frame and "
                  "detects none (its scene records pairs only; contact_counts: [0, 1, 2] "
                  "learns a count), so every untouched frame is a phantom: a known miss."]
    lines += ["", "Script: " + result["script"] + "."]
    return "\n".join(lines)


def _pct(value) -> str:
    if value is None:
        return "–"
    text = f"{100 * value:.2f}"
    if text in ("0.00", "100.00") and 0 < value < 1:
        # a share a frame short of none or all says so: "100.00 %" beside a missed target
        # read as a contradiction
        text = f"{100 * value:.4f}".rstrip("0")
    return f"{text} %"


def _spread(cv: dict[str, Any], name: str, scale: float, unit: str) -> str:
    if name not in cv:
        return "–"
    mean, sd = cv[name]
    return f"{mean * scale:.3g} ± {sd * scale:.2g}{unit}"


def describe(settings, stretches_mm: list[float], plan: ScenePlan) -> str:
    """The script in words, from its settings."""
    light = edge_presses(plan)
    held = (f"{settings.held_presses} presses of {settings.held_press_s:g} s, the stretch "
            "changed half-way" if len(stretches_mm) > 1
            else "no press held through a stretch change (trained at one stretch)")
    return (f"{len(light)} light edge and corner presses of {settings.light_press_s:g} s at "
            f"each of {stretches_mm} mm; {held}; {settings.taps} taps of "
            f"{settings.tap_ms:g} ms; presses of {settings.long_presses_min} min, each "
            f"followed by {settings.after_long_s:g} s untouched; "
            f"{settings.untouched_min:g} min untouched at {max(stretches_mm):g} mm; "
            f"{settings.untouched_s:g} s untouched between presses; each press ramping over "
            f"{settings.press_ramp_ms:g} ms; the board's drift SD "
            f"{settings.drift_offset_pf:g} pF; seed {settings.seed}")


# ---------------------------------------------------------------- the README's copy

README = Path("README.md")
README_SCENE = ONE_CONTACT.name  # the paper's one-contact scene, named as its kind
BEGIN, END = "<!-- hard_hour table: python -m harness.hard_hour -->", "<!-- /hard_hour table -->"


def table_of(report_md: str) -> str:
    """The table's lines of a reports/hard_hour/<scene>.md."""
    return "\n".join(line for line in report_md.splitlines() if line.startswith("|"))


def quoted_in_readme(readme: str) -> str:
    """The table the README quotes between its markers."""
    start, end = readme.index(BEGIN) + len(BEGIN), readme.index(END)
    return readme[start:end].strip()


def quote_in_readme(readme: Path = README, scene: str = README_SCENE) -> None:
    """Copy reports/hard_hour/<scene>.md's table into the README, between its markers."""
    text = readme.read_text(encoding="utf-8")
    table = table_of((Path("reports/hard_hour") / f"{scene}.md").read_text(encoding="utf-8"))
    start, end = text.index(BEGIN) + len(BEGIN), text.index(END)
    readme.write_text(text[:start] + "\n" + table + "\n" + text[end:], encoding="utf-8")


if __name__ == "__main__":
    quote_in_readme()
    sys.exit(0)
