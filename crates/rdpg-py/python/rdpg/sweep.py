"""The Ray Tune part of ``rdpg sweep``: ``python -m rdpg.sweep PLAN.json``.

``rdpg sweep FILE`` parses and checks the sweep file, writes ``runs/sweeps/<name>/plan.json``
(every trial's run directory, base config and overrides) and replaces itself with this module.
Each trial is one ``rdpg train`` process driven by a function trainable: it forwards every
validation evaluation of the run (``metrics.jsonl``) with ``tune.report`` and hands Tune a small
checkpoint naming the run directory and its step -- never the directory itself, which holds the
replay and can be hundreds of MB. Rerunning the command restores the Tune experiment: unfinished
trials continue with ``rdpg train --resume``, finished ones are skipped. A trial that finishes
has its small result file written (``rdpg sweep FILE --collect``) for ``rdpg table``.

Stopping. Ctrl-C or SIGTERM to the driver, or ``rdpg sweep FILE --stop`` from any shell (it
leaves the stop marker ``<storage>/stop.json`` and waits for the driver, which names itself in
``<storage>/driver.json`` while it runs), stops the sweep: each running ``rdpg train`` gets one
SIGTERM, and the driver exits only when every one has saved its checkpoint. A trial's ``rdpg
train`` stopped from outside (it saves and exits with 130) stops the whole sweep the same way,
rather than counting as a failure that lets the next trial start. Each running trial has a
record ``<storage>/running/<trial>.json`` (its process and run directory) while it runs.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time


def _finished(trial: dict) -> dict | None:
    """The trial's summary once its run ended at its budget, else None. A run has ended when
    its test is written; a tuning trial (``"tuning": true`` in the plan) runs no test and has
    ended once its final validation, at the budget, is written (as ``rdpg sweep --collect``
    decides). Read from its run directory, or, where that is gone (another machine), from its
    committed result file (``results/<sweep>/<trial>.json``), so a finished trial never runs
    again."""
    try:
        with open(os.path.join(trial["run_dir"], "summary.json")) as f:
            summary = json.load(f)
    except (OSError, ValueError):
        summary = None
    if summary is None and not os.path.exists(trial["run_dir"]) and trial.get("result"):
        try:
            with open(trial["result"]) as f:
                summary = json.load(f)["summary"]
        except (OSError, ValueError, KeyError, TypeError):
            summary = None
    if not summary or summary.get("steps", 0) < trial["steps"]:
        return None
    if trial.get("tuning"):
        ended = (summary.get("last_eval") or {}).get("step", -1) >= trial["steps"]
    else:
        ended = bool(summary.get("test_eval"))
    return summary if ended else None


def _wait_unlocked(run_dir: str) -> None:
    """Waits while another ``rdpg train`` holds the run (e.g. one still saving after a stop)."""
    import fcntl

    path = os.path.join(run_dir, ".lock")
    if not os.path.exists(path):
        return
    with open(path, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        fcntl.flock(f, fcntl.LOCK_UN)


# `rdpg train` exits with 130 when a signal stopped it after saving its checkpoint.
_INTERRUPTED = 130


def _running_dir(storage: str) -> str:
    return os.path.join(storage, "running")


def _stop_marker(storage: str) -> str:
    return os.path.join(storage, "stop.json")


def _driver_record(storage: str) -> str:
    return os.path.join(storage, "driver.json")


def _alive(pid: int, run_dir: str) -> bool:
    """Whether ``pid`` is still the ``rdpg train`` of ``run_dir`` (not a reused pid)."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return run_dir.encode() in f.read()
    except OSError:
        return False


def _stop_once(storage: str, trial_id: str, pid: int, run_dir: str) -> bool:
    """Sends the trial's ``rdpg train`` its one SIGTERM, unless this driver already did. True
    when this call is the one that sent it."""
    flag = os.path.join(_running_dir(storage), trial_id + ".stopping")
    try:
        os.close(os.open(flag, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    if _alive(pid, run_dir):
        os.kill(pid, signal.SIGTERM)
    return True


def _stop_all_and_wait(storage: str) -> list[str]:
    """Stops every running trial's ``rdpg train`` (one SIGTERM each) and waits until each has
    saved and released its run. Returns the trials it waited for."""
    d = _running_dir(storage)
    waited = []
    for name in sorted(os.listdir(d)) if os.path.isdir(d) else []:
        if not name.endswith(".json"):
            continue
        trial_id = name[: -len(".json")]
        try:
            with open(os.path.join(d, name)) as f:
                rec = json.load(f)
        except (OSError, ValueError):
            continue
        if _alive(rec["pid"], rec["run_dir"]):
            _stop_once(storage, trial_id, rec["pid"], rec["run_dir"])
            _wait_unlocked(rec["run_dir"])
            waited.append(trial_id)
        for stale in (name, trial_id + ".stopping"):
            try:
                os.remove(os.path.join(d, stale))
            except FileNotFoundError:
                pass
    return waited


def _checkpoint(run_dir: str, step: int):
    from ray import tune

    d = tempfile.mkdtemp(prefix="rdpg-trial-")
    with open(os.path.join(d, "trial.json"), "w") as f:
        json.dump({"run_dir": run_dir, "step": step}, f)
    return tune.Checkpoint.from_directory(d)


def make_trainable(plan: dict):
    trials = {t["id"]: t for t in plan["trials"]}
    binary, cwd, storage = plan["binary"], plan["cwd"], plan["storage"]

    def collect() -> None:
        subprocess.run(
            [binary, "sweep", plan["sweep_file"], "--collect"],
            cwd=cwd,
            check=True,
            stdout=subprocess.DEVNULL,
        )

    def trainable(config: dict) -> None:
        from ray import tune

        t = trials[config["trial"]]
        run_dir = t["run_dir"]
        if os.path.exists(_stop_marker(storage)):
            # The sweep is stopping: start nothing new (the rerun resumes this trial).
            raise RuntimeError(f"trial {t['id']}: not started, the sweep is stopping")
        last_step = -1
        ckpt = tune.get_checkpoint()
        if ckpt is not None:
            with ckpt.as_directory() as d:
                with open(os.path.join(d, "trial.json")) as f:
                    info = json.load(f)
            if info["run_dir"] != run_dir:
                raise RuntimeError(
                    f"trial {t['id']}: Tune's checkpoint names {info['run_dir']}, the plan {run_dir}"
                )
            last_step = info["step"]
        _wait_unlocked(run_dir)
        summary = _finished(t)
        if summary is None:
            if os.path.exists(os.path.join(run_dir, "checkpoints", "latest", "manifest.json")):
                args = [binary, "train", "--quiet", "--resume", run_dir]
            else:
                # Started but never checkpointed: nothing to keep, start again.
                shutil.rmtree(run_dir, ignore_errors=True)
                args = [binary, "train", "--quiet", "--config", t["base"], "--out", run_dir]
                for s in t["set"]:
                    args += ["--set", s]
            os.makedirs(os.path.dirname(run_dir), exist_ok=True)
            log_path = run_dir + ".log"
            with open(log_path, "ab") as log:
                # Its own session: a stop reaches it as the SIGTERM below, never as a Ctrl-C
                # through the terminal's process group (a second Ctrl-C exits without saving).
                proc = subprocess.Popen(
                    args, cwd=cwd, stdout=log, stderr=log, start_new_session=True
                )
                running = os.path.join(_running_dir(storage), t["id"] + ".json")
                os.makedirs(os.path.dirname(running), exist_ok=True)
                with open(running, "w") as f:
                    json.dump({"pid": proc.pid, "run_dir": run_dir}, f)
                metrics, offset = os.path.join(run_dir, "metrics.jsonl"), 0
                try:
                    while True:
                        rc = proc.poll()
                        offset, last_step = _report_evals(metrics, offset, last_step, run_dir)
                        if rc is not None:
                            break
                        time.sleep(1.0)
                finally:
                    # Stopped by Tune or failing: one SIGTERM, and no wait (Ray may end this
                    # worker at any moment): the run saves its checkpoint and exits on its own
                    # (Ray is told to leave a worker's children alone); the driver waits for it
                    # before it exits, and a rerun waits for its lock.
                    if proc.poll() is None:
                        _stop_once(storage, t["id"], proc.pid, run_dir)
            stopped_here = os.path.exists(running[: -len(".json")] + ".stopping")
            for done in (running, running[: -len(".json")] + ".stopping"):
                try:
                    os.remove(done)
                except FileNotFoundError:
                    pass
            if rc == _INTERRUPTED and not stopped_here:
                # Stopped from outside, its checkpoint saved: the operator is stopping the
                # sweep, not this trial failing. The driver sees the marker and stops Tune.
                with open(_stop_marker(storage), "w") as f:
                    json.dump({"trial": t["id"]}, f)
                raise RuntimeError(f"trial {t['id']}: stopped from outside at its checkpoint")
            if rc != 0:
                with open(log_path, "rb") as f:
                    tail = f.read()[-2000:].decode(errors="replace")
                raise RuntimeError(f"trial {t['id']}: rdpg train exited with {rc}:\n{tail}")
            summary = _finished(t)
            if summary is None:
                raise RuntimeError(f"trial {t['id']}: rdpg train ended before its budget")
        collect()
        report = {"step": summary["steps"], "finished": True}
        test = summary.get("test_eval")
        if test:
            report["test_mean_stock_return"] = test["mean_stock_return"]
            report["test_success_rate"] = test["success_rate"]
        tune.report(report, checkpoint=_checkpoint(run_dir, summary["steps"]))

    return trainable


def _report_evals(metrics: str, offset: int, last_step: int, run_dir: str):
    """Reports the evaluation rows appended to ``metrics`` since ``offset`` (whole lines
    only; a resumed run cuts the file back, so a shorter file restarts from 0)."""
    from ray import tune

    try:
        size = os.path.getsize(metrics)
    except OSError:
        return offset, last_step
    if size < offset:
        offset = 0
    with open(metrics, "rb") as f:
        f.seek(offset)
        data = f.read()
    end = data.rfind(b"\n") + 1
    for line in data[:end].splitlines():
        try:
            row = json.loads(line)
        except ValueError:
            continue
        if row.get("kind") != "eval" or row["step"] <= last_step:
            continue
        last_step = row["step"]
        tune.report(
            {
                "step": row["step"],
                "mean_return": row["mean_return"],
                "success_rate": row["success_rate"],
                "finished": False,
            },
            checkpoint=_checkpoint(run_dir, row["step"]),
        )
    return offset + end, last_step


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: python -m rdpg.sweep PLAN.json (written by `rdpg sweep FILE`)", file=sys.stderr)
        return 2
    with open(argv[1]) as f:
        plan = json.load(f)
    # One small checkpoint per evaluation is what the sweep wants; Tune's advice against
    # frequent experiment snapshots does not apply.
    os.environ.setdefault("TUNE_WARN_EXCESSIVE_EXPERIMENT_CHECKPOINT_SYNC_THRESHOLD_S", "0")
    # A stopped trial's `rdpg train` must get the time to save its checkpoint after its SIGTERM,
    # where Ray would kill a worker's children with the worker.
    os.environ.setdefault("RAY_kill_child_processes_on_worker_exit", "0")
    os.environ.setdefault("RAY_kill_child_processes_on_worker_exit_with_raylet_subreaper", "0")
    import ray
    from ray import tune

    storage = plan["storage"]
    path = os.path.join(storage, "tune")
    # Tune restores an experiment as it was defined: a sweep file whose trials changed since
    # its runs started is refused rather than half-applied.
    key = [[t["id"], t["base"], t["set"]] for t in plan["trials"]]
    stored = os.path.join(storage, "trials.json")
    if os.path.exists(stored):
        with open(stored) as f:
            if json.load(f) != key:
                print(
                    f"error: the trials of sweep {plan['name']} changed since its runs started "
                    f"({stored}); give the changed sweep another name",
                    file=sys.stderr,
                )
                return 2
    else:
        with open(stored, "w") as f:
            json.dump(key, f)
    # Left by an earlier stop: the trials it names resume now.
    if os.path.exists(_stop_marker(storage)):
        os.remove(_stop_marker(storage))
    _stop_all_and_wait(storage)
    stopping = threading.Event()

    def stop_sweep(*_args) -> None:
        # Tune ends a run on SIGINT as on Ctrl-C: trials stop, its state is saved.
        if not stopping.is_set():
            stopping.set()
            os.kill(os.getpid(), signal.SIGINT)

    signal.signal(signal.SIGTERM, stop_sweep)

    def watch_marker() -> None:
        while not stopping.is_set():
            if os.path.exists(_stop_marker(storage)):
                stop_sweep()
            time.sleep(0.5)

    threading.Thread(target=watch_marker, daemon=True).start()
    if plan.get("address"):
        ray.init(address=plan["address"])
    else:
        # Trials exchange only small dicts through Ray: a small object store (Ray's default
        # reserves 30 % of the machine's memory) leaves the memory to the runs.
        ray.init(
            num_cpus=plan["cpus"],
            include_dashboard=False,
            object_store_memory=200 * 1024 * 1024,
        )
    # Who drives the sweep, for `rdpg sweep FILE --stop` (removed when the driver exits; one
    # left by a driver that died names a process that is gone, which `--stop` checks).
    with open(_driver_record(storage), "w") as f:
        json.dump({"pid": os.getpid(), "plan": argv[1]}, f)
    try:
        fn = tune.with_resources(make_trainable(plan), {"cpu": plan["threads"]})
        if tune.Tuner.can_restore(path):
            tuner = tune.Tuner.restore(path, trainable=fn, resume_errored=True)
        else:
            tuner = tune.Tuner(
                fn,
                param_space={"trial": tune.grid_search([t["id"] for t in plan["trials"]])},
                tune_config=tune.TuneConfig(
                    max_concurrent_trials=max(1, plan["cpus"] // plan["threads"])
                ),
                run_config=tune.RunConfig(
                    name="tune",
                    storage_path=storage,
                    checkpoint_config=tune.CheckpointConfig(num_to_keep=1),
                    verbose=1,
                ),
            )
        grid = tuner.fit()
        errors = [str(r.error) for r in grid if r.error]
    finally:
        stopping.set()
        waited = _stop_all_and_wait(storage)
        if waited:
            print(f"saved and stopped: {', '.join(waited)}", file=sys.stderr)
        ray.shutdown()
        if os.path.exists(_driver_record(storage)):
            os.remove(_driver_record(storage))
    if os.path.exists(_stop_marker(storage)):
        with open(_stop_marker(storage)) as f:
            marker = json.load(f)
        why = (
            f"trial {marker['trial']} was stopped from outside"
            if "trial" in marker
            else f"stopped by `{marker.get('by', 'a stop marker')}`"
        )
        print(
            f"the sweep stopped: {why}; rerun the command to continue every unfinished trial",
            file=sys.stderr,
        )
    finished = [t["id"] for t in plan["trials"] if _finished(t)]
    print(
        json.dumps(
            {
                "sweep": plan["name"],
                "trials": len(plan["trials"]),
                "finished": len(finished),
                "errors": errors,
            }
        )
    )
    return 0 if len(finished) == len(plan["trials"]) else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv))
