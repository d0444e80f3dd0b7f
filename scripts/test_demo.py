"""scripts/demo.py's job runner on tiny jobs: dependencies run first, a failed job skips
only its dependents, stdout can go to a file, and `--only` selects jobs with their needs."""

import importlib.util
import pathlib
import sys

import pytest

spec = importlib.util.spec_from_file_location(
    "demo", pathlib.Path(__file__).with_name("demo.py"))
demo = importlib.util.module_from_spec(spec)
sys.modules["demo"] = demo  # dataclasses look their module up while the class is built
spec.loader.exec_module(demo)
# The report reads what the plan writes.
report_spec = importlib.util.spec_from_file_location(
    "report", pathlib.Path(__file__).with_name("report.py"))
report = importlib.util.module_from_spec(report_spec)
report_spec.loader.exec_module(report)


def python(code):
    return [sys.executable, "-c", code]


def test_a_failed_job_skips_its_dependents_and_the_others_run(tmp_path):
    trail = tmp_path / "trail.txt"

    def append(word):
        return python(f"open({str(trail)!r}, 'a').write({word!r} + ' ')")

    jobs = [
        demo.Job("first", [append("first")]),
        demo.Job("second", [append("second")], after=["first"]),
        demo.Job("broken", [python("import sys; sys.exit(3)")]),
        demo.Job("needs-broken", [append("never")], after=["broken"]),
        demo.Job("after-that", [append("never")], after=["needs-broken"]),
        demo.Job("printer", [python("print('to the file')")], stdout=tmp_path / "out.txt"),
    ]
    runner = demo.Runner(tmp_path, slots=2)
    done, failed = runner.run(jobs)
    assert sorted(done) == ["first", "printer", "second"]
    assert [f.log.name for f in failed] == ["broken.log"]
    assert "exited with 3" in str(failed[0])
    assert trail.read_text().split() == ["first", "second"]
    assert (tmp_path / "out.txt").read_text() == "to the file\n"
    assert "$ " in (tmp_path / "first.log").read_text()


def test_unknown_dependencies_are_refused(tmp_path):
    with pytest.raises(ValueError, match="unknown jobs"):
        demo.Runner(tmp_path, slots=1).run([demo.Job("a", [], after=["missing"])])


def test_only_keeps_the_named_jobs_and_what_they_need():
    jobs = [demo.Job("record", []), demo.Job("train", [], after=["record"]),
            demo.Job("evaluate", [], after=["train"]), demo.Job("other", [])]
    assert [j.name for j in demo.needed(jobs, ["eval"])] == ["record", "train", "evaluate"]
    with pytest.raises(SystemExit, match="no job starts with"):
        demo.needed(jobs, ["nothing"])


def test_the_plan_covers_every_experiment_the_report_reads(tmp_path):
    jobs = demo.plan(tmp_path)
    names = {job.name for job in jobs}
    for name in ("pouring-record-train", "pouring-perturb", "pouring-push", "pouring-context",
                 "obstacles-3", "obstacles-3-baseline", "stability-obstacles-3-baseline",
                 "limit-cycle-field", "limit-cycle-10-seed2", "pouring-0.1-seed2", "pouring-joint-range-push",
                 "robot-loop-flow", "robot-loop-joint-range-pushed", "reach-ur5e",
                 "reach-iiwa14"):
        assert name in names
    # The reach jobs write the files the report's section reads, for both of its arms.
    reach = {job.name: job for job in jobs if job.name.startswith("reach-")}
    for arm, _label in report.REACH_ARMS:
        written = [str(arg) for command in reach[f"reach-{arm}"].commands for arg in command]
        assert str(tmp_path / "experiments" / "reach" / f"{arm}.json") in written
        assert str(tmp_path / "experiments" / "reach" / f"{arm}-expert.json") in written
        # The MLP trained beside the policy, evaluated from the policy's directory.
        train = next(c for c in reach[f"reach-{arm}"].commands if "train" in map(str, c))
        assert "--baseline" in train
        policy = str(train[train.index("--out") + 1])
        control = next(c for c in reach[f"reach-{arm}"].commands
                       if str(c[-1]).endswith(f"{arm}-baseline.json"))
        assert str(control[control.index("--checkpoint") + 1]) == f"{policy}/baseline"
    # The pouring control: the MLP trained beside one full-data model, evaluated from
    # that model's directory into the files the report's pouring section reads.
    fraction, seed = demo.POURING_CONTROL
    trained = next(job for job in jobs if job.name == f"pouring-{fraction}-seed{seed}")
    assert "--baseline" in trained.commands[0]
    policy = str(trained.commands[0][trained.commands[0].index("--out") + 1])
    control = next(job for job in jobs if job.name == "pouring-baseline")
    assert control.after == [trained.name]
    for command, mode in zip(control.commands, report.POURING_MODES):
        assert str(command[command.index("--checkpoint") + 1]) == f"{policy}/baseline"
        assert str(command[-1]) == str(tmp_path / "experiments" / "pouring" / f"baseline-{mode}.json")
    check = next(job for job in jobs if job.name == "stability-pouring-baseline")
    assert str(check.commands[0][check.commands[0].index("--checkpoint") + 1]) == f"{policy}/baseline"
    assert check.stdout == tmp_path / "experiments" / "stability" / "pouring-baseline.json"
    # The limit cycles' closed-loop runs: the MLP trained beside the model the runs
    # evaluate, every actor on both context sets, into the files the report reads.
    for family in ("limit-cycle", "limit-cycle-curled"):
        n = max(demo.LIMIT_CYCLE_TRAJECTORIES)
        trained = next(job for job in jobs if job.name == f"{family}-{n}-seed0")
        assert "--baseline" in trained.commands[0]
        policy = str(trained.commands[0][trained.commands[0].index("--out") + 1])
        runs = next(job for job in jobs if job.name == f"{family}-closed-loop")
        assert runs.after == [trained.name]
        folder = tmp_path / "experiments" / family.replace("-", "_") / "closed_loop"
        written = {str(command[-1]): command for command in runs.commands}
        for actor, _ in report.LIMIT_CYCLE_ACTORS:
            for contexts, _ in report.LIMIT_CYCLE_CONTEXTS:
                command = written[str(folder / f"{actor}-{contexts}.json")]
                if actor != "expert":
                    checkpoint = str(command[command.index("--checkpoint") + 1])
                    assert checkpoint == (policy if actor == "flow" else f"{policy}/baseline")
    # Each obstacle model is evaluated where the report's obstacle section reads it.
    obstacle_files = {"obstacles-3-baseline": "3-baseline/eval.json",
                      "obstacles-1-generic": "1-generic/eval.json",
                      "obstacles-2-generic": "2-generic/eval.json",
                      "obstacles-3-generic": "3-generic/field.json"}
    for name, file in obstacle_files.items():
        job = next(job for job in jobs if job.name == name)
        written = [str(arg) for command in job.commands for arg in command]
        assert str(tmp_path / "experiments" / "obstacles" / file) in written, name
    # Every obstacle model also runs on the demonstrations' own episodes: the recording's
    # seed and episode count, so the same contexts and starts.
    record = next(job for job in jobs if job.name == "record-obstacles-3").commands[0]
    recorded = (record[record.index("--seed") + 1], record[record.index("--episodes") + 1])
    for name in ("obstacles-1", "obstacles-3-generic", "obstacles-3-baseline"):
        job = next(job for job in jobs if job.name == name)
        command = next(c for c in job.commands if any(str(a).endswith("eval_demos.json")
                                                      for a in c))
        assert (command[command.index("--seed") + 1],
                command[command.index("--episodes") + 1]) == recorded, name
    # Every obstacle flow's stability check runs through the robot too.
    for k in demo.OBSTACLE_COUNTS:
        check = next(job for job in jobs if job.name == f"stability-obstacles-{k}-flow")
        assert "--robot-loop" in check.commands[0], k
    assert all(set(job.after) <= names for job in jobs)
