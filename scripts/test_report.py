"""scripts/report.py on small synthetic `ciflow evaluate` JSON: tables with mean ± std over
seeds, targets with pass/fail, PNG figures, and "not run" lines for missing experiments."""

import importlib.util
import json
import pathlib

import pytest

spec = importlib.util.spec_from_file_location(
    "report", pathlib.Path(__file__).with_name("report.py"))
report = importlib.util.module_from_spec(spec)
spec.loader.exec_module(report)


def write(path, value):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(value))


def trace(n, context, with_point=True):
    q = [[0.01 * k, 0.02 * k] for k in range(n)]
    return {
        "time": [0.01 * k for k in range(n)],
        "q": q,
        "qd": [[0.0, 0.0]] * n,
        "command": [[0.0, 0.0]] * (n - 1),
        "context": [context] * n,
        "point": [[x, y, 0.3] for x, y in q] if with_point else q,
    }


def evaluation(success_rate, episodes, disturbance, push=None, example=True):
    context = [0.0, 0.3, 0.8, -0.1]
    results = [{"seed": i, "success": i < round(success_rate * episodes), "start": [0.0, 0.0],
                "context": context, "collision": False} for i in range(episodes)]
    return {
        "episodes": episodes,
        "success_rate": success_rate,
        "collision_rate": 0.0,
        "spill_rate": 0.0,
        "final_distance": {"mean": 0.01, "std": 0.002},
        "disturbance": disturbance,
        "results": results,
        "trajectories": [trace(20, context, with_point=False)],
        "push": push,
        "example": {"trace": trace(20, context), "reference": trace(20, context)} if example else None,
    }


def field_json(contexts=([0.0], [0.5], [1.0])):
    grid = [[0.1, -0.2, 0.3], [0.0, 0.5, -0.1], [0.2, 0.2, 0.2]]
    return {
        "window": [-1, 1, -1, 1],
        "fields": [{
            "context": c,
            "x": [-1, 0, 1],
            "y": [-1, 0, 1],
            "velocity_x": grid,
            "velocity_y": grid[::-1],
            "rollouts": [[[0.9, 0.9], [0.5, 0.5], [0.1, 0.0]]],
            "latent_grid": [[[-1, 0], [1, 0]], [[0, -1], [0, 1]]],
        } for c in contexts],
        "demonstrations": [{"context": [0.0], "points": [[0.5, 0.5], [0.0, 0.0]]}],
    }


@pytest.fixture
def experiments(tmp_path):
    root = tmp_path / "experiments"
    write(root / "limit_cycle" / "field.json", field_json())
    for seed, value in enumerate((1.0, 2.0, 3.0)):
        write(root / "limit_cycle" / "nll" / f"5_seed{seed}_train.json", {"per_transition": value})
        write(root / "limit_cycle" / "nll" / f"5_seed{seed}_test.json", {"per_transition": value - 1})
    # Closed loop: the flow and the MLP on both context sets, the expert on the held-out
    # ones only (its other file missing: a "not run" row).
    for actor, contexts, success, distance, speed in (
            ("flow", "training", 0.98, 0.0136, 0.80), ("flow", "held_out", 0.95, 0.0154, 0.79),
            ("baseline", "training", 0.35, 0.0477, 0.55),
            ("baseline", "held_out", 0.47, 0.0414, 0.50),
            ("expert", "held_out", 1.0, 0.0005, 0.80)):
        run = evaluation(success, 100, {"mode": "none"})
        run["second_half_distance"] = {"mean": distance, "max": 2 * distance}
        run["second_half_speed"] = {"mean": speed, "min": speed / 10}
        write(root / "limit_cycle" / "closed_loop" / f"{actor}-{contexts}.json", run)
    # The curled family: its curve only, and no field (a "not run" line).
    for seed, value in enumerate((4.0, 5.0, 6.0)):
        for split, offset in (("train", 0), ("test", 2)):
            write(root / "limit_cycle_curled" / "nll" / f"10_seed{seed}_{split}.json",
                  {"per_transition": value - offset})
    write(root / "obstacles" / "3" / "eval.json", evaluation(0.96, 100, {"mode": "none"}))
    write(root / "obstacles" / "3-generic" / "eval.json", evaluation(0.7, 100, {"mode": "none"}))
    write(root / "obstacles" / "1-generic" / "eval.json", evaluation(0.99, 100, {"mode": "none"}))
    write(root / "obstacles" / "3-generic" / "field.json", field_json([[0.0, 0.3, 0.8, -0.1]]))
    write(root / "obstacles" / "1-generic" / "field.json", field_json([[0.0, 0.3, 0.8, -0.1]]))
    baseline = evaluation(0.5, 100, {"mode": "none"})
    baseline["collision_rate"] = 0.25
    write(root / "obstacles" / "3-baseline" / "eval.json", baseline)
    # On the demonstrations' own episodes: the generic model and the control; the radial
    # model without this file gets no row.
    # The generic model's divided into the 800 fitted and 200 held-out demonstrations; the
    # control's from before training splits were recorded (no division).
    demonstrated = evaluation(0.6, 1000, {"mode": "none"})
    demonstrated["collision_rate"] = 0.4
    write(root / "obstacles" / "3-baseline" / "eval_demos.json", demonstrated)
    demonstrated["training_split"] = {
        "fitted": {"episodes": 800, "success_rate": 0.625, "collision_rate": 0.375},
        "held_out": {"episodes": 200, "success_rate": 0.5, "collision_rate": 0.5},
        "not_in_data": None,
    }
    write(root / "obstacles" / "3-generic" / "eval_demos.json", demonstrated)
    write(root / "pouring" / "eval.json", evaluation(0.85, 100, {"mode": "none"}))
    push = {
        "required_displacement": 0.05,
        "displacement": {"mean": 0.07, "std": 0.01, "min": 0.055, "max": 0.09, "count": 10},
        "recovery_tolerance": 0.01,
        "recovered_within_deadline_fraction": 0.9,
    }
    write(root / "pouring" / "push.json",
          evaluation(0.8, 10, {"mode": "push", "start": 0.05, "duration": 0.05}, push=push))
    # Two training seeds' full-data models; seed 1 has no context run.
    for seed, rate in ((0, 0.9), (1, 0.7)):
        write(root / "pouring" / "seeds" / f"eval_seed{seed}.json",
              evaluation(rate, 10, {"mode": "none"}))
        write(root / "pouring" / "seeds" / f"push_seed{seed}.json",
              evaluation(rate, 10, {"mode": "push", "start": 0.05, "duration": 0.05},
                         push={**push, "recovered_within_deadline_fraction": rate - 0.1}))
    write(root / "pouring" / "seeds" / "context_seed0.json",
          evaluation(1.0, 10, {"mode": "context", "time": 1.0}))
    # The expert's run of the same pushes: shown beside the policy's figures.
    write(root / "pouring" / "expert-push.json",
          evaluation(1.0, 10, {"mode": "push", "start": 0.05, "duration": 0.05},
                     push={**push, "recovered_within_deadline_fraction": 1.0}))
    # The unconstrained MLP's runs of the same episodes; it has no pot-moved run.
    control = evaluation(0.3, 100, {"mode": "none"})
    control["spill_rate"] = 0.25
    write(root / "pouring" / "baseline-eval.json", control)
    write(root / "pouring" / "baseline-push.json",
          evaluation(0.2, 10, {"mode": "push", "start": 0.05, "duration": 0.05},
                     push={**push, "recovered_within_deadline_fraction": 0.1}))
    def within(*fractions):
        return [{"factor": f, "fraction": x} for f, x in zip((1, 10, 100, 1000), fractions)]
    write(root / "stability" / "pouring-flow.json", {
        "observation_space": {"fraction": 1.0, "rollouts": 50, "diverged_to_non_finite": 0,
                              "stalled_away": 0, "within": within(1.0, 1.0, 1.0, 1.0),
                              "context_scale": 1.0, "left_start_box": 3,
                              "largest_reach": 212.4},
        "far_contexts": {"fraction": 0.98, "rollouts": 50, "diverged_to_non_finite": 1,
                         "stalled_away": 0, "within": within(0.98, 0.98, 0.98, 0.98),
                         "context_scale": 10.0},
        "negative_control": {"fraction": 0.0, "rollouts": 40},
        "robot_loop": {"fraction": 0.95, "rollouts": 20},
    })
    write(root / "stability" / "pouring-baseline.json", {
        "observation_space": {"fraction": 0.4, "rollouts": 50, "diverged_to_non_finite": 3,
                              "stalled_away": 5, "within": within(0.4, 0.5, 0.6, 0.7)},
    })
    def robot_loop(hits, saturated, traced, push=None):
        trace = {"period": 0.1, "positions": [[0.1 * k, -0.2] for k in range(5)]}
        return {"robot_loop": {"rollouts": 100, "converged": 100, "hit_end_stops": hits,
                               "push": push,
                               "steps": 1000, "saturated_step_fraction": saturated,
                               "over_speed_steps": 7, "held_steps": 130,
                               "position_min": [-1.0, -1.0],
                               "position_max": [1.0, 1.0], "traces": [trace] * traced}}
    write(root / "robot_loop" / "flow.json", robot_loop(42, 0.065, 2))
    write(root / "robot_loop" / "joint-range-pushed.json",
          robot_loop(3, 0.012, 0, {"force": 40.0, "at": 1.0, "duration": 0.2}))
    reach = evaluation(0.96, 50, {"mode": "none"})
    reach["final_distance"] = {"count": 50, "mean": 0.004, "std": 0.002, "min": 0.001,
                               "max": 0.021}
    write(root / "reach" / "ur5e.json", reach)
    write(root / "reach" / "ur5e-expert.json", evaluation(1.0, 50, {"mode": "none"}))
    control = evaluation(0.4, 50, {"mode": "none"})
    control["final_distance"] = {"count": 50, "mean": 0.03, "std": 0.01, "min": 0.002,
                                 "max": 0.09}
    write(root / "reach" / "ur5e-baseline.json", control)
    samples = [{"time": 0.01 * k, "state": [0.1 * k] * 7, "command": [1.0] * 7,
                "reward": -0.5 + 0.005 * k, "running": True, "episode_done": k == 99}
               for k in range(100)]
    write(root / "pouring" / "perturb.json", {
        "events": [{"kind": "push", "start": 0.3, "duration": 0.2},
                   {"kind": "context", "start": 0.6, "duration": 0.0}],
        "samples": samples,
    })
    return root


def test_report_states_targets_tables_and_missing_experiments(experiments, tmp_path):
    output = report.build(experiments, tmp_path / "out" / "report.md")
    text = output.read_text()
    # Mean ± population std over the three seeds: train 2 ± 0.816, test 1 ± 0.816.
    assert "| 5 | 2.000 ± 0.816 | 1.000 ± 0.816 | 3 |" in text
    assert "| 10 | 5.000 ± 0.816 | 3.000 ± 0.816 | 3 |" in text
    assert "curled contexts: vector fields and rollouts: not run" in text
    # The limit cycle closed loop: each actor and context set from its own file.
    assert ("| stable flow (10 trajectories, seed 0) | held-out contexts | 100 | 95.0% | "
            "1.54 cm (3.08 cm) | 0.79 m/s (0.08 m/s) |") in text
    assert ("| unconstrained MLP (control) | training contexts | 100 | 35.0% | 4.77 cm (9.54 cm) | "
            "0.55 m/s (0.06 m/s) |") in text
    assert "| expert | training contexts | not run | | | |" in text
    assert "the closed-loop runs beside the unconstrained MLP: not run" in text
    assert "| goal reached, 3 obstacles | 96.0% (collisions 0.0%) | ≥ 95% | **pass** |" in text
    assert ("| goal reached, 3 obstacles, generic INN | 70.0% (collisions 0.0%) | ≥ 95% | "
            "**FAIL** |") in text
    # One obstacle asks for 98%: 99% passes; without a file the line says "not run".
    assert ("| goal reached, 1 obstacle, generic INN | 99.0% (collisions 0.0%) | ≥ 98% | "
            "**pass** |") in text
    assert "| goal reached, 2 obstacles, generic INN | not run | ≥ 98% | — |" in text
    assert "| goal reached, 1 obstacle | not run | ≥ 98% | — |" in text
    generic = text[text.index("The paper's generic model"):]
    assert "| 1 | 100 | 99.0% | 0.0% | 0.0100 ± 0.0020 |" in generic
    assert "| 3 | 100 | 70.0% | 0.0% | 0.0100 ± 0.0020 |" in generic
    assert "| success, no perturbation (100 contexts) | 85.0% | ≥ 90% | **FAIL** |" in text
    assert "| push displacement (min over episodes) | 5.5 cm | ≥ 5 cm | **pass** |" in text
    assert ("| success under pushes (10 episodes) | 80.0% (expert 100.0%) | ≥ 90% | **FAIL** |"
            in text)
    assert "90.0% (expert 100.0%) | ≥ 90% of pushes | **pass** |" in text
    # The policy, the MLP and the expert on the same episodes, each from its own files.
    assert ("| stable flow (the demo's policy) | 85.0% | 80.0% | 90.0% | not run |"
            in text)
    assert "| unconstrained MLP (control) | 30.0% | 20.0% | 10.0% | not run | 25.0% |" in text
    assert "| expert | not run | 100.0% | 100.0% | not run | — |" in text
    assert "| 0 | 90.0% | 90.0% | 80.0% | 100.0% |" in text
    assert "| 1 | 70.0% | 70.0% | 60.0% | not run |" in text
    assert ("| mean (range) | 80.0% (70.0%–90.0%) | 80.0% (70.0%–90.0%) | 70.0% (60.0%–80.0%) | "
            "100.0% (100.0%–100.0%) |") in text
    assert "2 obstacle(s): not run" in text
    assert ("| 3 obstacles, generic INN | 0 of 0 | 0 of 0 | 0 of 100 | 0 of 100 |") in text
    assert ("| 3 obstacles, unconstrained MLP (control) | 50.0% | 25.0% | 0.0100 ± 0.0020 |"
            in text)
    assert ("| 3 obstacles, unconstrained MLP (control) | 0 of 0 | 0 of 0 | 0 of 100 | "
            "0 of 100 |") in text
    assert "pot moved mid-motion: not run" in text
    # Held-out beside the demonstrations' own episodes, for the models that have both.
    assert ("| 3 obstacles, generic INN | 70.0% of 100 | 0.0% | 62.5% of 800 | 37.5% | "
            "50.0% of 200 | 50.0% |") in text
    assert ("| 3 obstacles, unconstrained MLP (control) | 50.0% of 100 | 25.0% | 60.0% of 1000 | "
            "40.0% (fitted and held out together) | — | — |") in text
    assert "| 3 obstacles, radial contractions | 96.0% of 100 |" not in text
    # The collision target: met by the radial model's 0 of 100; a rate above 1% fails.
    assert "| collisions, 3 obstacles | 0.0% of 100 episodes | ≤ 1% | **pass** |" in text
    assert ("| pouring-flow | training box | 100.0% | 100.0% / 100.0% / 100.0% | 50 | 0 | 0 | "
            "3 (212×) | 100.0% of 40 | 95.0% of 20 |") in text
    assert ("| pouring-flow | up to 10.0× outside | 98.0% | 98.0% / 98.0% / 98.0% | 50 | 1 | 0 "
            "| — |  |  |") in text
    assert ("| pouring-baseline | training box | 40.0% | 50.0% / 60.0% / 70.0% | 50 | 3 | 5 | "
            "— | — | not run |") in text
    assert "| flow | — | 100 of 100 | 42 | 6.5% of 1000 | 7 | 130 |" in text
    assert ("| joint-range | 40 N for 0.2 s on the hand at 1 s | 100 of 100 | 3 | 1.2% of 1000 | 7 |"
            in text)
    assert ("| UR5e | 96.0% (50 goals) | ≥ 90%: **pass** | 4.0 mm (21.0 mm) | "
            "40.0%, 30.0 mm (90.0 mm) | 100.0% |" in text)
    assert "| KUKA LBR iiwa 14 | not run | ≥ 90% | | | |" in text
    assert ("session ran 0.99 simulated s (100 telemetry samples) and ended with the spout "
            "0.5 cm from the pour point") in text
    figures = tmp_path / "out" / "figures"
    for name in ("limit_cycle_field.png", "limit_cycle_nll.png", "limit_cycle_curled_nll.png",
                 "obstacles_rollouts.png",
                 "obstacles_generic_rollouts.png", "obstacles_3_generic_field.png",
                 "obstacles_1_generic_field.png",
                 "pouring_push.png", "pouring_script_run.png", "stability.png",
                 "joint_limits.png"):
        assert (figures / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
        assert f"(figures/{name})" in text


def test_collisions_are_classed_by_where_the_obstacles_sit(tmp_path):
    # Start (0, 0), target (1, 0): one obstacle on the line, one 8 cm off it, one 30 cm.
    contexts = [[0.5, 0.0, 2.0, 2.0, 1.0, 0.0],
                [0.5, 0.08, 2.0, 2.0, 1.0, 0.0],
                [0.5, 0.3, 2.0, 2.0, 1.0, 0.0]]
    assert [report.straight_line_clearance([0.0, 0.0], c) for c in contexts] == \
        pytest.approx([0.0, 0.08, 0.3])
    # Past the target the segment's end is nearest, not the line's foot.
    assert report.straight_line_clearance([0.0, 0.0], [1.3, 0.4, 1.0, 0.0]) == \
        pytest.approx(0.5)

    def evaluation(collisions):
        return {"results": [{"start": [0.0, 0.0], "context": c, "collision": hit}
                            for c, hit in zip(contexts, collisions)]}

    out = report.Report(tmp_path / "report.md")
    report.collisions_by_geometry(out, [("model", evaluation([True, False, False])),
                                        ("older file", {"results": [{"context": contexts[0]}]})])
    text = "\n".join(out.lines)
    assert "| straight start-target line (no avoidance) | 1 of 1 | 1 of 1 | 0 of 1 | 2 of 3 |" \
        in text
    assert "| model | 1 of 1 | 0 of 1 | 0 of 1 | 1 of 3 |" in text
    assert "older file" not in text


def test_more_than_one_percent_collisions_fails_the_three_obstacle_target(tmp_path):
    root = tmp_path / "experiments"
    radial = evaluation(0.989, 1000, {"mode": "none"})
    radial["collision_rate"] = 0.011
    write(root / "obstacles" / "3" / "eval.json", radial)
    text = report.build(root, tmp_path / "report.md").read_text()
    assert "| goal reached, 3 obstacles | 98.9% (collisions 1.1%) | ≥ 95% | **pass** |" in text
    assert "| collisions, 3 obstacles | 1.1% of 1000 episodes | ≤ 1% | **FAIL** |" in text


def test_an_empty_directory_gives_not_run_lines(tmp_path):
    text = report.build(tmp_path / "nothing", tmp_path / "report.md").read_text()
    assert text.count("not run") >= 8
    assert "**pass**" not in text and "**FAIL**" not in text


def test_a_malformed_file_is_reported_not_raised(tmp_path):
    root = tmp_path / "experiments"
    write(root / "pouring" / "eval.json", {"episodes": 3})
    text = report.build(root, tmp_path / "report.md").read_text()
    assert "pouring: could not be read (KeyError" in text
    assert "## Stability" in text


def test_a_spilled_script_run_says_so(experiments, tmp_path):
    script = experiments / "pouring" / "perturb.json"
    run = json.loads(script.read_text())
    run["samples"][-1]["reward"] = report.SPILL_REWARD
    write(script, run)
    text = report.build(experiments, tmp_path / "report.md").read_text()
    assert "(100 telemetry samples) and ended in a spill." in text
