"""The experiments' report: PNG figures and a Markdown summary from `ciflow evaluate` JSON.

Usage: python scripts/report.py [EXPERIMENTS_DIR] [REPORT_MD]
(defaults: out/experiments and out/report.md; figures go to REPORT_MD's folder/figures).

Layout of EXPERIMENTS_DIR (every file optional: a missing one gives a "not run" line):

    limit_cycle/field.json            ciflow evaluate --field (contexts 0;0.5;1, --field-demos)
    limit_cycle/nll/<N>_seed<S>_train.json, <N>_seed<S>_test.json
                                      ciflow evaluate --nll DATASET --out (N trajectories)
    limit_cycle_curled/...            the same for the curled outlines (contexts 1;1.5;2)
    obstacles/<K>/eval.json           ciflow evaluate --kwarg obstacles=K --episodes 100+
                                      --trajectories 8 (K = 1, 2, 3)
    obstacles/<K>/field.json          ciflow evaluate --field (optional latent-grid figure)
    obstacles/<K>-generic/{eval,field}.json  the same for the generic INN (no contractions)
    obstacles/<K>[-generic]/eval_demos.json, obstacles/3-baseline/eval_demos.json
                                      ciflow evaluate on the demonstrations' own episodes
                                      (the recording's seeds: its contexts and starts),
                                      fitted and held-out ones apart (training_split)
    pouring/nll/<F>_seed<S>_train.json, <F>_seed<S>_test.json   (F: fraction of the demos)
    pouring/eval.json                 ciflow evaluate (no perturbation), 100 episodes
    pouring/push.json                 ciflow evaluate --perturb push
    pouring/context.json              ciflow evaluate --perturb context
    pouring/perturb.json              python -m ciflow.perturb --record (a policy-driven
                                      session over Zenoh, pushed and its pot moved)
    stability/<name>.json             ciflow stability --json > ... (name e.g. pouring-flow,
                                      pouring-baseline: every trained policy and the baseline)
"""

import argparse
import json
import math
import pathlib
import re
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

# Targets of issues 6, 13 and 15. Obstacles: goal reached over the held-out contexts, by
# obstacle count.
OBSTACLE_GOAL_TARGETS = {1: 0.98, 2: 0.98, 3: 0.95}
# ... and at most this share of collisions (issue 13 states it for 3 obstacles).
OBSTACLE_COLLISION_TARGETS = {3: 0.01}
# Pouring: success without and under pushes, recovery within the deadline, success with
# the pot moved mid-motion (issue 15 raised the push figures from 80 %).
POURING_TARGET = 0.90
PUSH_DISPLACEMENT_TARGET = 0.05  # m
RECOVERY_DEADLINE = 2.0  # s
# The obstacle-avoidance task's obstacle body radius (m), drawn in the figures, and the
# margin its expert keeps (envs/src/tasks/obstacle_avoidance.rs `SAFETY_RADIUS`).
OBSTACLE_RADIUS = 0.1
SAFETY_RADIUS = 0.16
# Where an obstacle sits relative to the straight start-target line, by the distance of
# the nearest centre from it (m): the classes of the collisions-by-geometry table.
OBSTACLE_GEOMETRY = (("head-on", 0.0, OBSTACLE_RADIUS / 2),
                     ("grazing", OBSTACLE_RADIUS / 2, SAFETY_RADIUS),
                     ("clear", SAFETY_RADIUS, math.inf))
# Pouring's reward on a spill (envs/src/tasks/pouring.rs `SPILL_REWARD`).
SPILL_REWARD = -100.0
NLL_NAME = re.compile(r"^(?P<x>[0-9]+(?:\.[0-9]+)?)_seed(?P<seed>[0-9]+)_(?P<split>train|test)\.json$")


def load(path):
    """The JSON at `path`, or None when it does not exist."""
    path = pathlib.Path(path)
    if not path.is_file():
        return None
    return json.loads(path.read_text())


def as_array(values):
    """JSON numbers to floats; `null` (a non-finite value) becomes NaN."""
    return np.array([[math.nan if v is None else v for v in row] for row in values], float)


def percent(x):
    return "n/a" if x is None else f"{100.0 * x:.1f}%"


def verdict(ok):
    return "**pass**" if ok else "**FAIL**"


def mean_std(values):
    values = np.asarray(values, float)
    return float(values.mean()), float(values.std())


class Report:
    """Markdown lines and the figures folder."""

    def __init__(self, figures):
        self.lines = []
        self.figures = pathlib.Path(figures)
        self.figures.mkdir(parents=True, exist_ok=True)

    def add(self, *lines):
        self.lines.extend(lines)

    def not_run(self, what, path):
        self.add(f"- {what}: not run (no `{path}`)")

    def figure(self, fig, name, caption):
        fig.tight_layout()
        fig.savefig(self.figures / name, dpi=110)
        plt.close(fig)
        self.add("", f"![{caption}](figures/{name})", "")

    def target(self, what, measured, target_text, ok):
        self.add(f"| {what} | {measured} | {target_text} | {verdict(ok)} |")


# ---- figures ----------------------------------------------------------------------------


def draw_obstacles(ax, context):
    """Obstacle discs and target of an obstacle-avoidance context `[o1, …, g]`."""
    points = np.array(context, float).reshape(-1, 2)
    for o in points[:-1]:
        ax.add_patch(plt.Circle(o, OBSTACLE_RADIUS, color="0.6"))
    ax.plot(*points[-1], "g*", ms=10)


def plot_field(report, field, name, title, obstacles=False):
    """Per context: streamlines, rollouts and demonstrations (top), latent grid (bottom)."""
    fields = field["fields"]
    fig, axes = plt.subplots(2, len(fields), figsize=(4.2 * len(fields), 8), squeeze=False)
    for col, f in enumerate(fields):
        top, bottom = axes[0][col], axes[1][col]
        x, y = np.array(f["x"]), np.array(f["y"])
        u, v = as_array(f["velocity_x"]), as_array(f["velocity_y"])
        finite = np.isfinite(u) & np.isfinite(v)
        u, v = np.where(finite, u, 0.0), np.where(finite, v, 0.0)
        if np.hypot(u, v).max() > 0:
            top.streamplot(x, y, u, v, color="0.7", linewidth=0.6, density=1.2, arrowsize=0.6)
        context = np.array(f["context"], float)
        demonstrated = False
        for demo in field.get("demonstrations", []):
            if np.allclose(demo["context"], context, atol=1e-6):
                demonstrated = True
                p = np.array(demo["points"], float)
                top.plot(p[:, 0], p[:, 1], ":", color="0.3", lw=1)
        if f.get("reference"):
            p = np.array(f["reference"], float)
            top.plot(p[:, 0], p[:, 1], "--", color="k", lw=1.4, label="true outline", zorder=5)
            top.legend(loc="lower right", fontsize=7)
        for path in f["rollouts"]:
            p = np.array(path, float)
            top.plot(p[:, 0], p[:, 1], color="tab:blue", lw=1.2)
            top.plot(p[0, 0], p[0, 1], "o", color="tab:blue", ms=3)
        for line in f["latent_grid"]:
            p = np.array(line, float)
            bottom.plot(p[:, 0], p[:, 1], color="tab:purple", lw=0.7)
        label = ", ".join(f"{c:.2f}" for c in context)
        panel = f"c = ({label})" if len(context) < 4 else f"layout {col + 1}"
        if field.get("demonstrations"):
            panel += " — trained" if demonstrated else " — held out"
        top.set_title(panel)
        bottom.set_title("f(latent grid, c)")
        for ax in (top, bottom):
            if obstacles:
                draw_obstacles(ax, context)
            ax.set_xlim(field["window"][0], field["window"][1])
            ax.set_ylim(field["window"][2], field["window"][3])
            ax.set_aspect("equal")
    fig.suptitle(title)
    report.figure(fig, name, title)


def nll_points(folder):
    """{split: {x: [log-likelihood per transition over seeds]}} from `folder`."""
    points = {"train": {}, "test": {}}
    for path in sorted(pathlib.Path(folder).glob("*.json")):
        match = NLL_NAME.match(path.name)
        if match:
            x = float(match["x"])
            points[match["split"]].setdefault(x, []).append(load(path)["per_transition"])
    return points


def plot_nll(report, points, name, xlabel, title):
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for split, color in (("train", "tab:blue"), ("test", "tab:orange")):
        xs = sorted(points[split])
        if xs:
            stats = [mean_std(points[split][x]) for x in xs]
            ax.errorbar(xs, [m for m, _ in stats], yerr=[s for _, s in stats], marker="o",
                        capsize=3, color=color, label=split)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("log-likelihood per transition (nats)")
    ax.legend()
    ax.set_title(title)
    report.figure(fig, name, title)


def nll_table(report, points, xlabel):
    report.add("", f"| {xlabel} | train (mean ± std) | test (mean ± std) | seeds |", "|---|---|---|---|")
    for x in sorted(set(points["train"]) | set(points["test"])):
        cells = []
        for split in ("train", "test"):
            values = points[split].get(x)
            cells.append("—" if not values else "{:.3f} ± {:.3f}".format(*mean_std(values)))
        seeds = max(len(points["train"].get(x, [])), len(points["test"].get(x, [])))
        report.add(f"| {x:g} | {cells[0]} | {cells[1]} | {seeds} |")


def learning_curve(report, folder, table_label, axis_label, name, title):
    """Train and test log-likelihood against the amount of data: table and figure."""
    points = nll_points(folder)
    if not points["train"] and not points["test"]:
        report.not_run(f"log-likelihood versus {axis_label}", folder)
        return
    nll_table(report, points, table_label)
    plot_nll(report, points, name, axis_label, title)


def plot_trajectories(report, evaluations, name, title):
    """Closed-loop obstacle-avoidance rollouts: one row per obstacle count."""
    rows = [(k, e) for k, e in evaluations if e.get("trajectories")]
    if not rows:
        return
    cols = max(min(4, len(e["trajectories"])) for _, e in rows)
    fig, axes = plt.subplots(len(rows), cols, figsize=(3.2 * cols, 3.2 * len(rows)), squeeze=False)
    for r, (k, evaluation) in enumerate(rows):
        for c in range(cols):
            ax = axes[r][c]
            traces = evaluation["trajectories"]
            if c >= len(traces):
                ax.axis("off")
                continue
            trace, result = traces[c], evaluation["results"][c]
            draw_obstacles(ax, trace["context"][0])
            q = np.array(trace["q"], float)
            color = "tab:blue" if result["success"] else "tab:red"
            ax.plot(q[:, 0], q[:, 1], color=color)
            ax.plot(q[0, 0], q[0, 1], "ko", ms=3)
            ax.set_aspect("equal")
            ax.set_title(f"{k} obstacle(s), seed {result['seed']}", fontsize=9)
    fig.suptitle(title)
    report.figure(fig, name, title)


def plot_disturbed(report, evaluation, name, title):
    """State, command and tool-point traces of the example episode, with its reference."""
    example = evaluation.get("example")
    if not example:
        return
    trace, reference = example["trace"], example.get("reference")
    t = np.array(trace["time"], float)
    fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    q, command = np.array(trace["q"], float), np.array(trace["command"], float)
    for j in range(q.shape[1]):
        line, = axes[0].plot(t, q[:, j], lw=1, label=f"q{j + 1}")
        if reference:
            r = np.array(reference["q"], float)
            axes[0].plot(np.array(reference["time"]), r[:, j], "--", lw=0.8, color=line.get_color())
        axes[1].plot(t[:-1], command[:, j], lw=0.8, color=line.get_color())
    axes[0].set_ylabel("q (dashed: unpushed)")
    axes[0].legend(ncol=7, fontsize=7)
    axes[1].set_ylabel("command q̈_des")
    point = np.array(trace["point"], float)
    for j, axis in enumerate("xyz"[: point.shape[1]]):
        line, = axes[2].plot(t, point[:, j], lw=1, label=axis)
        if reference:
            r = np.array(reference["point"], float)
            axes[2].plot(np.array(reference["time"]), r[:, j], "--", lw=0.8, color=line.get_color())
    axes[2].set_ylabel("tool point (m)")
    axes[2].set_xlabel("time (s)")
    axes[2].legend(fontsize=8)
    disturbance = evaluation["disturbance"]
    for ax in axes:
        if disturbance["mode"] == "push":
            start = disturbance["start"]
            ax.axvspan(start, start + disturbance["duration"], color="tab:red", alpha=0.2)
        elif disturbance["mode"] == "context":
            ax.axvline(disturbance["time"], color="tab:red", ls=":")
    fig.suptitle(title)
    report.figure(fig, name, title)


# ---- sections ---------------------------------------------------------------------------


def limit_cycle(report, root):
    report.add("## Limit cycle", "")
    families = (
        ("limit_cycle", "", "phases", "the ten training phases, 0 and 1 included (2 → {0, 1})",
         "{0.25, 0.5, 0.75}", "Limit cycle (10 phases fitted)"),
        ("limit_cycle_curled", "_curled", "curled contexts",
         "the ten curled training contexts, 1 and 2 included (2 → {1, 2})",
         "{1.25, 1.5, 1.75}", "Curled outlines (10 contexts fitted)"))
    for folder_name, suffix, what, fitted, held_out, title in families:
        folder = root / folder_name
        if suffix:
            report.add("### Curled outlines", "",
                       "For contexts c ∈ [1, 2] the raised figure curls its limbs into hooks: "
                       "the outlines are no longer star-shaped about the centre (a ray from it "
                       "crosses the outline three times from c ≈ 1.15, five from c ≈ 1.8), so no "
                       "polar radius describes them, and success is measured by the Euclidean "
                       "distance to the curve.", "")
        field = load(folder / "field.json")
        if field is None:
            report.not_run(f"{what}: vector fields and rollouts", folder / "field.json")
        else:
            plot_field(report, field, f"limit_cycle{suffix}_field.png",
                       f"{title}: learned field, rollouts (blue), demonstrations (dotted), "
                       "true outline (dashed)")
        limit_cycle_closed_loop(report, folder / "closed_loop", held_out)
        report.add(f"Learning curve: the n-trajectory model fits n distinct {what} spread evenly "
                   f"over {fitted}; none is held out of the fit and the last epoch is kept, so "
                   "*train* is the log-likelihood of exactly the demonstrations fitted and *test* "
                   f"that of the held-out contexts {held_out}.", "")
        learning_curve(report, folder / "nll", "training trajectories", "training trajectories",
                       f"limit_cycle{suffix}_nll.png",
                       f"{title.split(' (')[0]}: log-likelihood per transition")


# The actors of the limit-cycle closed-loop runs and the context sets they run on, as
# `scripts/demo.py` names their files (`<actor>-<contexts>.json`).
LIMIT_CYCLE_ACTORS = (("flow", "stable flow (10 trajectories, seed 0)"),
                      ("baseline", "unconstrained MLP (control)"), ("expert", "expert"))
LIMIT_CYCLE_CONTEXTS = (("training", "training contexts"), ("held_out", "held-out contexts"))


def limit_cycle_closed_loop(report, folder, held_out):
    """The flow, the MLP trained beside it and the expert, closed loop from the same new
    starts: on the outline at the end (success), and over each episode's second half the
    mean distance to the outline and the mean speed, which tells a motion that keeps
    circulating from one that stopped on the outline."""
    runs = {(actor, contexts): load(folder / f"{actor}-{contexts}.json")
            for actor, _ in LIMIT_CYCLE_ACTORS for contexts, _ in LIMIT_CYCLE_CONTEXTS}
    if not any(runs.values()):
        report.not_run("the closed-loop runs beside the unconstrained MLP",
                       folder / "flow-held_out.json")
        return
    report.add(f"Closed loop from new starts (held-out contexts {held_out}); success: within "
               "3 cm of the outline at the end of the 10 s episode; over the last 5 s: the mean "
               "distance to the outline and the mean speed (the expert circulates at 0.8 m/s), "
               "with the slowest episode's:", "",
               "| actor | contexts | episodes | success | distance to the outline, last 5 s: "
               "mean (worst episode) | speed, last 5 s: mean (slowest episode) |",
               "|---|---|---|---|---|---|")
    for actor, actor_name in LIMIT_CYCLE_ACTORS:
        for contexts, contexts_name in LIMIT_CYCLE_CONTEXTS:
            run = runs[(actor, contexts)]
            if run is None:
                report.add(f"| {actor_name} | {contexts_name} | not run | | | |")
                continue
            distance, speed = run.get("second_half_distance"), run.get("second_half_speed")
            distance = ("—" if distance is None else
                        f"{100 * distance['mean']:.2f} cm ({100 * distance['max']:.2f} cm)")
            speed = "—" if speed is None else f"{speed['mean']:.2f} m/s ({speed['min']:.2f} m/s)"
            report.add(f"| {actor_name} | {contexts_name} | {run['episodes']} | "
                       f"{percent(run['success_rate'])} | {distance} | {speed} |")
    report.add("")


def straight_line_clearance(start, context):
    """Distance (m) from the straight segment between `start` and the target of the
    obstacle-avoidance context `[o1, …, g]` to the nearest obstacle centre."""
    points = np.array(context, float).reshape(-1, 2)
    centres, target, start = points[:-1], points[-1], np.asarray(start, float)
    direction = target - start
    along = np.clip((centres - start) @ direction / (direction @ direction), 0.0, 1.0)
    nearest = start + along[:, None] * direction
    return float(np.min(np.linalg.norm(centres - nearest, axis=1)))


def geometry_class(clearance):
    return next(name for name, low, high in OBSTACLE_GEOMETRY if low <= clearance < high)


def collisions_by_geometry(report, evaluations):
    """Collisions of each evaluation by where the obstacles sit, beside those of the
    straight start-target line (no avoidance at all) on the first one's contexts: what a
    model adds over going straight. Needs the results' `start` (older files lack it)."""
    rows = [(name, [r for r in e["results"] if r.get("start")]) for name, e in evaluations]
    rows = [(name, results) for name, results in rows if results]
    if not rows:
        return
    names = [name for name, _, _ in OBSTACLE_GEOMETRY]

    def cells(outcomes):
        counts = [[hit for kind, hit in outcomes if kind == name] for name in names]
        counts.append([hit for _, hit in outcomes])
        return " | ".join(f"{sum(c)} of {len(c)}" for c in counts)

    def classified(results, hit):
        """`(class, hit(result, clearance))` per result."""
        clearances = (straight_line_clearance(r["start"], r["context"]) for r in results)
        return [(geometry_class(c), hit(r, c)) for r, c in zip(results, clearances)]

    report.add("", "Collisions by where the obstacles sit: the nearest obstacle centre's "
               f"distance from the straight start-target line (head-on: under "
               f"{OBSTACLE_RADIUS / 2 * 100:.0f} cm, grazing: up to the expert's "
               f"{SAFETY_RADIUS * 100:.0f} cm margin, clear: farther). The straight line "
               f"itself collides where it passes within {OBSTACLE_RADIUS * 100:.0f} cm of a "
               "centre.", "",
               "| motion | " + " | ".join(names) + " | all |",
               "|---|" + "---|" * (len(names) + 1))
    straight = classified(rows[0][1], lambda _, clearance: clearance < OBSTACLE_RADIUS)
    report.add(f"| straight start-target line (no avoidance) | {cells(straight)} |")
    for name, results in rows:
        collided = classified(results, lambda r, _: bool(r.get("collision")))
        report.add(f"| {name} | {cells(collided)} |")


def outcome_cells(evaluation):
    """Goal reached, collision and final distance: the cells an obstacle table's row shares."""
    d = evaluation.get("final_distance") or {}
    return (f"{percent(evaluation['success_rate'])} | "
            f"{percent(evaluation.get('collision_rate'))} | "
            f"{d.get('mean', math.nan):.4f} ± {d.get('std', math.nan):.4f}")


def per_count_table(report, evaluations, figure, title):
    """A model's evaluations by obstacle count, `[(k, evaluation)]`: a table and the
    rollouts' figure."""
    report.add("", "| obstacles | episodes | goal reached | collision | final distance (m) |",
               "|---|---|---|---|---|")
    for k, e in evaluations:
        report.add(f"| {k} | {e['episodes']} | {outcome_cells(e)} |")
    plot_trajectories(report, evaluations, figure, title)


def fields_by_count(report, folder, suffix="", label=""):
    """The learned field and latent-grid figure of each obstacle count whose model folder
    `<K><suffix>` has a field file, captioned `<K> obstacle(s)<label>`."""
    for k in (1, 2, 3):
        field = load(folder / f"{k}{suffix}" / "field.json")
        if field is not None:
            plot_field(report, field, f"obstacles_{k}{suffix.replace('-', '_')}_field.png",
                       f"{k} obstacle(s){label}: learned field and deformation of a latent "
                       "grid", obstacles=True)


def obstacles(report, root):
    report.add("## Obstacle avoidance", "")
    folder = root / "obstacles"
    evaluations = []
    for k in (1, 2, 3):
        evaluation = load(folder / str(k) / "eval.json")
        if evaluation is None:
            report.not_run(f"{k} obstacle(s)", folder / str(k) / "eval.json")
        else:
            evaluations.append((k, evaluation))
    if evaluations:
        per_count_table(report, evaluations, "obstacles_rollouts.png",
                        "Obstacle avoidance: closed-loop rollouts (red: failed)")
    fields_by_count(report, folder)
    generic = [(k, e) for k in (1, 2, 3)
               if (e := load(folder / f"{k}-generic" / "eval.json")) is not None]
    if generic:
        report.add("", "The paper's generic model (no radial contractions: the obstacle set "
                   "enters the couplings' conditioners only through the set encoder), on the "
                   "same episodes:")
        per_count_table(report, generic, "obstacles_generic_rollouts.png",
                        "Obstacle avoidance, generic INN: closed-loop rollouts (red: failed)")
    radial, generic = dict(evaluations), dict(generic)
    baseline_eval = load(folder / "3-baseline" / "eval.json")
    three_models = [(name, e) for name, e in
                    (("3 obstacles, radial contractions", radial.get(3)),
                     ("3 obstacles, generic INN", generic.get(3)),
                     ("3 obstacles, unconstrained MLP (control)", baseline_eval))
                    if e is not None]
    if len(three_models) > 1:
        report.add("", "The same held-out episodes, each model:", "",
                   "| model | goal reached | collision | final distance (m) |",
                   "|---|---|---|---|")
        for name, e in three_models:
            report.add(f"| {name} | {outcome_cells(e)} |")
    collisions_by_geometry(report, three_models)
    held_out_and_demonstrated(report, folder, radial, generic, baseline_eval)
    fields_by_count(report, folder, "-generic", ", generic INN")
    report.add("", "| target | measured | required | |", "|---|---|---|---|")
    for k, target in OBSTACLE_GOAL_TARGETS.items():
        for model, results in (("", radial), (", generic INN", generic)):
            obstacles = f"{obstacle_label(k)}{model}"
            evaluation = results.get(k)
            if evaluation is None:
                report.add(f"| goal reached, {obstacles} | not run | ≥ {target:.0%} | — |")
                continue
            rate, collisions = evaluation["success_rate"], evaluation.get("collision_rate")
            report.target(f"goal reached, {obstacles}",
                          f"{percent(rate)} (collisions {percent(collisions)})",
                          f"≥ {target:.0%}", rate >= target)
            if k in OBSTACLE_COLLISION_TARGETS:
                limit = OBSTACLE_COLLISION_TARGETS[k]
                report.target(f"collisions, {obstacles}",
                              f"{percent(collisions)} of {evaluation['episodes']} episodes",
                              f"≤ {limit:.0%}", collisions is not None and collisions <= limit)
    report.add("")


def obstacle_label(k):
    return f"{k} obstacle{'s' if k > 1 else ''}"


def held_out_and_demonstrated(report, folder, radial, generic, baseline):
    """Each obstacle model on the held-out episodes (`radial`, `generic`: the evaluations
    already read, by obstacle count; `baseline`: the 3-obstacle control's) beside the
    demonstrations' own (the recording's contexts and starts, where the expert never
    collides), those the model was fitted to apart from those its training held out for
    validation (`ciflow evaluate`'s `training_split`): a model that fails on the fitted
    ones does not fit its data, one that fails only on unseen ones does not generalise."""
    models = [(f"{obstacle_label(k)}{label}", f"{k}{suffix}", held_out.get(k))
              for suffix, label, held_out in (("", ", radial contractions", radial),
                                              ("-generic", ", generic INN", generic))
              for k in (1, 2, 3)]
    models.append(("3 obstacles, unconstrained MLP (control)", "3-baseline", baseline))
    rows = [(name, held_out, demonstrated) for name, model, held_out in models
            if held_out is not None
            and (demonstrated := load(folder / model / "eval_demos.json")) is not None]
    if not rows:
        return
    report.add("", "Held-out episodes beside the demonstrations' own (their contexts and "
               "starts), split into those the model was fitted to and those its training "
               "held out for validation:", "",
               "| model | held-out episodes: goal reached | collision | fitted "
               "demonstrations: goal reached | collision | demonstrations held out of "
               "training: goal reached | collision |", "|---|---|---|---|---|---|---|")

    def cells(rates):
        if rates is None:
            return "n/a | n/a"
        return (f"{percent(rates['success_rate'])} of {rates['episodes']} | "
                f"{percent(rates.get('collision_rate'))}")

    for name, held_out, demonstrated in rows:
        split = demonstrated.get("training_split")
        if split is None:  # a checkpoint without its training split: both together
            own = f"{cells(demonstrated)} (fitted and held out together) | — | —"
        else:
            own = f"{cells(split.get('fitted'))} | {cells(split.get('held_out'))}"
        report.add(f"| {name} | {cells(held_out)} | {own} |")


SEED_FILE = re.compile(r"^(?P<mode>eval|push|context)_seed(?P<seed>[0-9]+)\.json$")


# The pouring figures of one actor, from its runs of the held-out episodes by mode:
# (column, mode, value of that mode's results).
POURING_COLUMNS = (("success", "eval", lambda r: r["success_rate"]),
                   ("under pushes", "push", lambda r: r["success_rate"]),
                   (f"back ≤ {RECOVERY_DEADLINE:g} s", "push",
                    lambda r: r["push"]["recovered_within_deadline_fraction"]),
                   ("pot moved", "context", lambda r: r["success_rate"]))
POURING_MODES = ("eval", "push", "context")


def pouring_beside_control(report, folder, policy, expert):
    """The demo's policy, the unconstrained MLP trained beside the same recipe (the same
    data, training seed, budget and widths; `--baseline`) and the expert, on the same
    held-out episodes, pushes and pot moves: what stability costs in accuracy."""
    control = {mode: load(folder / f"baseline-{mode}.json") for mode in POURING_MODES}
    if not any(control.values()):
        report.not_run("the unconstrained MLP on the same episodes",
                       folder / "baseline-eval.json")
        return
    report.add("The same held-out episodes, pushes and pot moves, each actor (the MLP fitted "
               "to the same demonstrations with the flow's training seed, budget and widths, "
               "and acting through the same controller law):", "",
               "| actor | " + " | ".join(c[0] for c in POURING_COLUMNS) + " | spilled |",
               "|---" * (len(POURING_COLUMNS) + 2) + "|")
    for name, runs in (("stable flow (the demo's policy)", policy),
                       ("unconstrained MLP (control)", control), ("expert", expert)):
        cells = ["not run" if runs.get(mode) is None else percent(value(runs[mode]))
                 for _, mode, value in POURING_COLUMNS]
        spill = (runs.get("eval") or {}).get("spill_rate")
        cells.append("—" if spill is None else percent(spill))
        report.add(f"| {name} | " + " | ".join(cells) + " |")
    report.add("")


def pouring_seeds(report, folder):
    """The closed-loop figures of the models trained on every demonstration with other
    training seeds (the learning curve's full-data models): how much of a figure is the
    seed. Rows are seeds, with the mean and range over them last."""
    runs = {}
    for path in sorted(folder.glob("*.json")) if folder.is_dir() else []:
        match = SEED_FILE.match(path.name)
        if match:
            runs.setdefault(int(match["seed"]), {})[match["mode"]] = load(path)
    if not runs:
        report.not_run("pouring over training seeds", folder)
        return
    report.add("The same figures for the models that fit every demonstration with training "
               "seeds 0, 1 and 2 (the learning curve's full-data models):", "",
               "| training seed | " + " | ".join(c[0] for c in POURING_COLUMNS) + " |",
               "|---" * (len(POURING_COLUMNS) + 1) + "|")
    values = {name: [] for name, _, _ in POURING_COLUMNS}
    for seed, modes in sorted(runs.items()):
        cells = []
        for name, mode, value in POURING_COLUMNS:
            result = modes.get(mode)
            if result is None:
                cells.append("not run")
            else:
                values[name].append(value(result))
                cells.append(percent(values[name][-1]))
        report.add(f"| {seed} | " + " | ".join(cells) + " |")
    summary = [f"{percent(np.mean(v))} ({percent(min(v))}–{percent(max(v))})" if v else "—"
               for v in values.values()]
    report.add("| mean (range) | " + " | ".join(summary) + " |", "")


def pouring(report, root):
    report.add("## Pouring", "")
    folder = root / "pouring"
    learning_curve(report, folder / "nll", "fraction of the recorded demonstrations",
                   "fraction of the demonstrations", "pouring_nll.png",
                   "Pouring: log-likelihood per transition")
    free, push, context = (load(folder / f"{n}.json") for n in POURING_MODES)
    # The demonstrator through the same episodes, disturbances and measures: what
    # imitating it can be expected to reach.
    expert = {n: load(folder / f"expert-{n}.json") for n in POURING_MODES}

    def with_expert(mode, measured, value):
        reference = expert[mode] and value(expert[mode])
        return measured if reference is None else f"{measured} (expert {percent(reference)})"

    def success(result):
        return result["success_rate"]

    def recovered(result):
        return (result.get("push") or {}).get("recovered_within_deadline_fraction")

    report.add("", "| target | measured (the expert, same episodes) | required | |",
               "|---|---|---|---|")
    if free is None:
        report.add(f"| success, no perturbation | not run | ≥ {POURING_TARGET:.0%} | — |")
    else:
        report.target(f"success, no perturbation ({free['episodes']} contexts)",
                      with_expert("eval", percent(free["success_rate"]), success),
                      f"≥ {POURING_TARGET:.0%}", free["success_rate"] >= POURING_TARGET)
    if push is None or not push.get("push"):
        report.add(f"| success under pushes | not run | ≥ {POURING_TARGET:.0%} | — |")
    else:
        summary = push["push"]
        low = summary["displacement"]["min"]
        report.target("push displacement (min over episodes)", f"{100 * low:.1f} cm",
                      f"≥ {100 * PUSH_DISPLACEMENT_TARGET:.0f} cm", low >= PUSH_DISPLACEMENT_TARGET)
        report.target(f"success under pushes ({push['episodes']} episodes)",
                      with_expert("push", percent(push["success_rate"]), success),
                      f"≥ {POURING_TARGET:.0%}", push["success_rate"] >= POURING_TARGET)
        within = summary["recovered_within_deadline_fraction"]
        report.target(
            f"back within {100 * summary['recovery_tolerance']:.1f} cm of the unpushed path "
            f"≤ {RECOVERY_DEADLINE:g} s after the push",
            with_expert("push", percent(within), recovered),
            f"≥ {POURING_TARGET:.0%} of pushes", within >= POURING_TARGET)
    if context is not None:
        report.target(f"success, pot moved at t = {context['disturbance']['time']} s",
                      with_expert("context", percent(context["success_rate"]), success),
                      f"≥ {POURING_TARGET:.0%}", context["success_rate"] >= POURING_TARGET)
    report.add("")
    if free is not None and free.get("spill_rate") is not None:
        report.add(f"Spill rate without perturbation: {percent(free['spill_rate'])}.", "")
    pouring_beside_control(report, folder, dict(zip(POURING_MODES, (free, push, context))),
                           expert)
    pouring_seeds(report, folder / "seeds")
    if push is None:
        report.not_run("push traces", folder / "push.json")
    else:
        plot_disturbed(report, push, "pouring_push.png",
                       "Pouring: pushed run (solid) and unpushed run (dashed); push shaded")
    if context is None:
        report.not_run("pot moved mid-motion", folder / "context.json")
    else:
        plot_disturbed(report, context, "pouring_context.png",
                       "Pouring: the pot moved mid-motion (dotted line)")
    script = load(folder / "perturb.json")
    if script is None:
        report.not_run("the perturbation script's run", folder / "perturb.json")
    else:
        plot_script_run(report, script)


def plot_script_run(report, script):
    """The engine's policy driving a session while `python -m ciflow.perturb` pushed it and
    moved the pot: joint positions and commands against simulated time."""
    samples = script["samples"]
    time = np.array([s["time"] for s in samples])
    fig, axes = plt.subplots(2, 1, sharex=True, figsize=(8, 5.5))
    for axis, field, label in ((axes[0], "state", "joint position (rad)"),
                               (axes[1], "command", "commanded q̈ (rad/s²)")):
        values = as_array([s[field] for s in samples])
        axis.plot(time, values[:, :7] if values.shape[1] >= 7 else values, lw=1)
        axis.set_ylabel(label)
        for event in script["events"]:
            color = "tab:red" if event["kind"] == "push" else "tab:blue"
            axis.axvspan(event["start"], event["start"] + max(event["duration"], 0.02),
                         color=color, alpha=0.2)
    axes[1].set_xlabel("simulated time (s)")
    last = samples[-1]
    if not last.get("episode_done"):
        ended = "was still running"
    elif last["reward"] <= SPILL_REWARD:
        ended = "ended in a spill"
    else:  # pouring's reward is minus the spout's distance to the pour point
        ended = f"ended with the spout {-100 * last['reward']:.1f} cm from the pour point"
    report.figure(fig, "pouring_script_run.png",
                  "Pouring over Zenoh: the engine's policy pushed (red) and its pot moved (blue) "
                  "by the perturbation script")
    report.add(f"The perturbation script's session ran {last['time']:.2f} simulated s "
               f"({len(samples)} telemetry samples) and {ended}. The run in 3-D, with its "
               "series and events, is the Rerun recording `pouring_perturb.rrd` beside this "
               "report (`rerun pouring_perturb.rrd`, or `python -m ciflow.view --record "
               "experiments/pouring/perturb.json`).", "")


def joint_limits(report, root):
    report.add("## Joint limits", "")
    folder = root / "robot_loop"
    runs = {p.stem: load(p) for p in sorted(folder.glob("*.json"))} if folder.is_dir() else {}
    if not runs:
        report.not_run("joint limits", folder)
        return
    report.add("The pouring policy driving the Panda through computed torque (`ciflow "
               "stability --robot-loop`): 100 rollouts from rest at joint positions drawn "
               "uniformly over the joint ranges, contexts from the training box, 60 s each "
               "at most. *flow* is the demo's policy; *joint-range* the same recipe trained "
               "with `--joint-range true` (the position ranges as the flow's last layer, the "
               "velocity time-scaled into the speed limits and braking distance, the "
               "acceleration scaled into its bounds, a quarter of them far from the data, an "
               "end-stop barrier on the measured state, and while the barrier holds the robot "
               "back the policy following its own latent state; README \"Joint limits\"). "
               "Targets of issue 16: 100 % converged, 0 end-stop hits, ≤ 1 % saturated steps.",
               "",
               "| policy | push | converged | rollouts at an end stop | control steps with "
               "torque or rate saturated | steps over a speed limit | steps on the latent "
               "reference |",
               "|---|---|---|---|---|---|---|")
    for name, run in runs.items():
        loop = run["robot_loop"]
        push = loop.get("push")
        described = "—" if push is None else (
            f"{push['force']:g} N for {push['duration']:g} s on the hand at {push['at']:g} s")
        report.add(f"| {name.removesuffix('-pushed')} | {described} | "
                   f"{loop['converged']} of {loop['rollouts']} | {loop['hit_end_stops']} | "
                   f"{percent(loop['saturated_step_fraction'])} of {loop['steps']} | "
                   f"{loop['over_speed_steps']} | {loop['held_steps']} |")
    shown = [(name, run["robot_loop"]) for name, run in runs.items()
             if not name.endswith("-pushed") and run["robot_loop"].get("traces")]
    if shown:
        joints = len(shown[0][1]["position_min"])
        fig, axes = plt.subplots(len(shown), joints, figsize=(2.2 * joints, 2.4 * len(shown)),
                                 squeeze=False, sharex=True)
        for row, (name, loop) in zip(axes, shown):
            for j, ax in enumerate(row):
                for trace in loop["traces"]:
                    q = np.array(trace["positions"])[:, j]
                    ax.plot(np.arange(len(q)) * trace["period"], q, lw=1)
                for limit in (loop["position_min"][j], loop["position_max"][j]):
                    ax.axhline(limit, color="tab:red", lw=1, ls="--")
                ax.set_title(f"{name}: joint {j + 1}", fontsize=8)
                ax.tick_params(labelsize=7)
        for ax in axes[-1]:
            ax.set_xlabel("s", fontsize=8)
        report.figure(fig, "joint_limits.png", "Joint positions of the first rollouts against "
                      "the Panda's limits (dashed)")
    evaluations = {mode: load(root / "pouring" / f"joint-range-{mode}.json")
                   for mode in ("eval", "push", "context")}
    if all(evaluations.values()):
        push = evaluations["push"].get("push") or {}
        report.add("", "The joint-range policy on the pouring evaluation's 100 held-out "
                   f"contexts: success {percent(evaluations['eval']['success_rate'])}, under "
                   f"≥ 5 cm pushes {percent(evaluations['push']['success_rate'])}, back on "
                   f"the path within 2 s {percent(push.get('recovered_within_deadline_fraction'))}"
                   f", pot moved at 1 s {percent(evaluations['context']['success_rate'])} "
                   "(the demo's policy: section Pouring).")


# The arms of the reach experiment, as scripts/demo.py names their files.
REACH_ARMS = (("ur5e", "UR5e"), ("iiwa14", "KUKA LBR iiwa 14"))


def reach(report, root):
    report.add("## Bring your own robot: reaching on arms that are not the Panda", "")
    folder = root / "reach"
    runs = [(label, *(load(folder / f"{arm}{suffix}.json") for suffix in ("", "-baseline",
                                                                          "-expert")))
            for arm, label in REACH_ARMS]
    if not any(policy for _, policy, _, _ in runs):
        report.not_run("reach", folder)
        return
    report.add("`ciflow/Reach-v0` with each arm given by its URDF (`engine/tests/assets`): "
               "the policy trained on 500 expert demonstrations, on new goals (held-out "
               "seeds), beside the unconstrained MLP trained with it (the same demonstrations "
               "and seed; `--baseline`) and the expert on the same goals. Target of issue 17: "
               "the tool ends within 1 cm of the goal in ≥ 90 %.", "",
               "| arm | policy within 1 cm | target | final distance, mean (max) | "
               "MLP (control) within 1 cm, final distance mean (max) | expert |",
               "|---|---|---|---|---|---|")

    def distance(run):
        shown = run.get("final_distance") or {}
        return (f"{1000 * shown['mean']:.1f} mm ({1000 * shown['max']:.1f} mm)"
                if shown else "n/a")

    for label, policy, control, expert in runs:
        if policy is None:
            report.add(f"| {label} | not run | ≥ 90% | | | |")
            continue
        control = (f"{percent(control['success_rate'])}, {distance(control)}" if control
                   else "not run")
        expert_rate = percent(expert["success_rate"]) if expert else "not run"
        report.add(f"| {label} | {percent(policy['success_rate'])} ({policy['episodes']} goals) "
                   f"| ≥ 90%: {verdict(policy['success_rate'] >= 0.9)} | {distance(policy)} "
                   f"| {control} | {expert_rate} |")


def stability(report, root):
    report.add("## Stability", "")
    folder = root / "stability"
    runs = sorted(folder.glob("*.json")) if folder.is_dir() else []
    if not runs:
        report.not_run("stability", folder)
        return
    report.add("Each policy's check runs rollouts from starts up to 100 times outside the "
               "demonstrations' box, with contexts from the training box and as many again with "
               "contexts up to 10 times its half-width outside it in the position-like "
               "coordinates (angles and the limit cycle's phase stay in their range). A flow "
               "converges for any weights, so its check runs on a negative control of "
               "the same class too: the same flow with its latent run backwards in time "
               "(`ciflow stability --negative-control`), of which the check must flag at "
               "least 99% (the command fails otherwise). No figure hangs on one threshold: "
               "*converged* is within the tolerance (1e-3 of the state box's diagonal), the "
               "next column the share ending within 10, 100 and 1000 times that. A rollout "
               "*stalls away* when its step stays below 1e-7 of the diagonal for 200 steps "
               "in a row farther than the tolerance from the attractor: the end point of a "
               "spurious attractor. Converging says nothing of the way there: *left the start "
               "box* counts the paths that went beyond the box their starts were drawn from "
               "(where a robot's end stops would be), with the farthest reach in "
               "demonstration boxes.",
               "", "| policy | contexts | converged | within 10× / 100× / 1000× the tolerance "
               "| rollouts | non-finite | stalled away (spurious attractors) | left the start "
               "box (farthest reach) | negative control flagged | through the robot loop |",
               "|---|---|---|---|---|---|---|---|---|---|")
    names, fractions = [], {"training": [], "far": []}
    for path in runs:
        measured = load(path)
        loop = measured.get("robot_loop")
        names.append(path.stem)
        through = "not run" if loop is None else f"{percent(loop['fraction'])} of {loop['rollouts']}"
        robot_control = measured.get("robot_loop_negative_control")
        if robot_control is not None:
            through += (f"; its negative control flagged in "
                        f"{percent(1 - robot_control['fraction'])} of {robot_control['rollouts']}")
        control = measured.get("negative_control")
        flagged = "—" if control is None else (
            f"{percent(1 - control['fraction'])} of {control['rollouts']}")
        for key, regime in (("observation_space", "training"), ("far_contexts", "far")):
            s = measured.get(key)
            if s is None:
                fractions[regime].append(float("nan"))
                continue
            fractions[regime].append(s["fraction"])
            contexts = ("training box" if regime == "training"
                        else f"up to {s.get('context_scale', '?')}× outside")
            looser = " / ".join(percent(w["fraction"]) for w in s.get("within", [])[1:]) or "—"
            left = ("—" if s.get("left_start_box") is None
                    else f"{s['left_start_box']} ({s['largest_reach']:.0f}×)")
            report.add(f"| {path.stem} | {contexts} | {percent(s['fraction'])} | {looser} | "
                       f"{s['rollouts']} | {s.get('diverged_to_non_finite', 0)} | "
                       f"{s.get('stalled_away', '—')} | {left} | "
                       f"{flagged if regime == 'training' else ''} | "
                       f"{through if regime == 'training' else ''} |")
    fig, ax = plt.subplots(figsize=(max(4, 1.4 * len(names)), 3.5))
    x = np.arange(len(names))
    for offset, (regime, label, color) in ((-0.2, ("training", "training contexts", "tab:blue")),
                                           (0.2, ("far", "contexts ≤10× outside", "tab:cyan"))):
        ax.bar(x + offset, [100 * f for f in fractions[regime]], width=0.4, label=label,
               color=color, edgecolor=["tab:red" if "baseline" in n else color for n in names],
               linewidth=2)
    ax.set_xticks(x, names)
    ax.set_ylabel("converged rollouts (%)")
    ax.set_ylim(0, 105)
    ax.legend(fontsize=8, loc="lower left")
    ax.tick_params(axis="x", rotation=30)
    report.figure(fig, "stability.png", "Rollouts converging from far outside the demonstrations")


def build(root, output):
    root, output = pathlib.Path(root), pathlib.Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    report = Report(output.parent / "figures")
    report.add("# C-IFlows experiments", "", f"Measured from `{root}` by `scripts/report.py`.", "")
    for section in (limit_cycle, obstacles, pouring, joint_limits, reach, stability):
        try:
            section(report, root)
        except (KeyError, ValueError, TypeError, IndexError, json.JSONDecodeError) as error:
            report.add(f"- {section.__name__}: could not be read ({type(error).__name__}: {error})")
        report.add("")
    output.write_text("\n".join(report.lines) + "\n")
    return output


def main(argv):
    parser = argparse.ArgumentParser(description="Write the report of `make demo`'s results.")
    parser.add_argument("root", nargs="?", default="out/experiments",
                        help="the experiments folder (default: out/experiments)")
    parser.add_argument("output", nargs="?", default="out/report.md",
                        help="the report to write; figures go beside it in figures/")
    args = parser.parse_args(argv[1:])
    if not pathlib.Path(args.root).is_dir():
        parser.error(f"{args.root} is not a folder of experiment results")
    print(f"wrote {build(args.root, args.output)}")


if __name__ == "__main__":
    main(sys.argv)
