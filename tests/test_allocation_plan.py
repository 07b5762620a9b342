"""The next device lease (scripts/merge_allocations.py --plan, pokeworld.remote.plan): the queue of
this checkout's configuration only, and commands whose every word is checked or shell-quoted."""

import json
import shlex
from pathlib import Path

import pytest
from allocation_planting import current_model

from pokeworld.errors import ConfigError
from pokeworld.experiments import stages
from pokeworld.experiments.presets import make_config
from pokeworld.remote import allocations, plan as ap
from pokeworld.remote.queue import split_folder_list

ROOT = Path(__file__).resolve().parents[1]


def _allocation(tmp_path, name, runs, configuration, finished=(), checkpoints=None, git="abc1234"):
    """An allocation whose runs' config.json say ``runs`` (name -> (variant, seed) as written), trained with the
    objective and model the `paper` preset trains now."""
    root = tmp_path / name
    for run, (variant, seed) in runs.items():
        (root / "runs" / run).mkdir(parents=True)
        (root / "runs" / run / "config.json").write_text(json.dumps(current_model(variant=variant, seed=seed)))
    return allocations.Allocation(name, root, {"git": git}, {"preset": "paper"}, "ab" * 32,
                                  {"finished": list(finished)}, checkpoints=dict(checkpoints or {}),
                                  configuration=configuration)


def test_the_configuration_key_is_the_corpus_a_checkout_generates(tmp_path):
    corpus = stages.ensure_corpus(make_config("tiny", out=str(tmp_path / "map"), num_episodes=6), "standard")
    manifest = json.loads((corpus / "manifest.json").read_text())
    assert ap.configuration_key(manifest["config"]) == ap.checkout_configuration_of(
        make_config("tiny", num_episodes=6))
    # another environment (here another seed) is another configuration
    assert ap.checkout_configuration_of(make_config("tiny", num_episodes=6, data_seed=1)) != \
        ap.configuration_key(manifest["config"])


def test_only_this_configurations_runs_count_and_others_are_named(tmp_path):
    old = _allocation(tmp_path, "old", {"VFX-s0": ("VFX", 0), "VF-s0": ("VF", 0)}, "aaaaaaaaaaaa",
                      finished=["VFX-s0", "VF-s0"], git="ad841ac")
    new = _allocation(tmp_path, "new", {"VFX-s0": ("VFX", 0), "V-s0": ("V", 0)}, "bbbbbbbbbbbb",
                      finished=["VFX-s0"], checkpoints={"V-s0": 700}, git="c0ffee1")
    p = allocations.plan([old, new], configuration="bbbbbbbbbbbb")
    # the old environment's VF does not count for the new one; the seed-0 factorial comes before seed 1, then seed
    # 2, then the other experiments' runs, by their run names (finding 2's single-horizon factorial first)
    assert p["queue"][:17] == ["V@0", "VF@0", "VX_t@0", "VX_p@0", "VX@0", "VFX@1", "VF@1", "V@1", "VX_t@1",
                               "VX_p@1", "VX@1", "VFX@2", "VF@2", "V@2", "VX_t@2", "VX_p@2", "VX@2"]
    assert p["queue"][17] == "V-h1-lam0.1-standard-motion_channelFalse-s0"
    assert len(p["queue"]) == len(set(p["queue"])) > 50
    assert p["finished"] == ["VFX@0"] and p["resume"] == {"V@0": {"step": 700, "from": "new"}}
    assert p["other_configurations"] == {"aaaaaaaaaaaa": {"finished": ["VF@0", "VFX@0"], "corpora": ["abababababab"],
                                                          "commits": ["ad841ac"]}}
    lines = ap.plan_lines(p, "c0ffee1")
    assert any("configuration aaaaaaaaaaaa (another environment" in x for x in lines)
    start, collect, final = lines[-5], lines[-3], lines[-1]
    words = shlex.split(start.split(" && ")[-1])
    assert words[:5] == ["ALLOC_COMMIT=c0ffee1", "ALLOC_RESUME=.resume/new", "bash", "scripts/gpu_lease.sh", "start"]
    assert words[6:] == p["queue"][:ap.LEASE_SHARE] and len(start) <= ap.MAX_COMMAND  # the lease's share
    assert start.startswith(ap.SETUP)
    assert (collect, final) == ('bash scripts/gpu_lease.sh collect "$OUT"', 'bash scripts/gpu_lease.sh final "$OUT"')


@pytest.mark.parametrize("variant, seed", [("VFX; touch /tmp/x", 0), ("VFX", "1; touch /tmp/x"), ("VFX", True),
                                           ("VFX", 1.5), ("VFX", -1), (["VFX"], 0)])
def test_a_returned_run_that_is_not_a_known_variant_and_whole_seed_is_refused(tmp_path, variant, seed):
    a = _allocation(tmp_path, "a", {"r": (variant, seed)}, "k", finished=["r"])
    with pytest.raises(ConfigError, match="is not (one of|an integer)"):
        allocations.plan([a], configuration="k")


def test_every_folder_and_the_commit_are_checked_or_quoted(tmp_path):
    runs = {"V-s0": ("V", 0)}
    hostile = _allocation(tmp_path, "$(id)>x", runs, "k", checkpoints={"V-s0": 10})
    p = allocations.plan([hostile], configuration="k")
    start = ap.plan_lines(p, "abc1234")[-5]
    env = shlex.split(start.split(" && ")[-1])[1]  # the shell's reading: one word, nothing run
    assert env.startswith("ALLOC_RESUME=") and split_folder_list(env.split("=", 1)[1]) == [".resume/$(id)>x"]
    with pytest.raises(ConfigError, match="hexadecimal"):
        ap.lease_commands(p, "abc1234; touch pwned")
    spaced = allocations.plan([_allocation(tmp_path, "a b", runs, "k", checkpoints={"V-s0": 10})], configuration="k")
    env = shlex.split(ap.plan_lines(spaced, "abc1234")[-5].split(" && ")[-1])[1]
    assert split_folder_list(env.split("=", 1)[1]) == [".resume/a b"]  # a folder with a space stays one


def test_every_folder_to_resume_from_is_copied_into_the_checkouts_resume_folder(tmp_path):
    # the device receives the checkout and the paths a call carries, nothing beside it, and the lease copies the
    # checkout without what .gitignore names (out/...): a returned folder is copied into .resume/ (ignored through
    # .git/info/exclude only) first, and ALLOC_RESUME names it as the device's copy sees it
    root = tmp_path / "repo"
    (root / ".resume" / "h200-1").mkdir(parents=True)
    elsewhere = [tmp_path / "x" / "h200-1", root / "out" / "h200-1", tmp_path / "$(id) a"]
    paths, copies = ap.device_folders([".resume/h200-1", *map(str, elsewhere)], root=root)
    assert paths == [".resume/h200-1", ".resume/h200-1-2", ".resume/h200-1-3", ".resume/$(id) a"]
    assert copies[0].startswith("mkdir -p .resume") and "/.resume/" in copies[0]
    assert [shlex.split(c)[-2:] for c in copies[1:]] == [[f"{o}/.", p] for o, p in zip(elsewhere, paths[1:])]
    assert ap.device_folders([".resume/h200-1"], root=root) == ([".resume/h200-1"], [])


def test_the_paper_queue_holds_every_experiment_of_the_map_in_the_papers_order():
    from pokeworld.remote.queue import PAPER_QUEUE, catalog, paper_queue
    from pokeworld.experiments.registry import EXPERIMENTS

    queue, specs = paper_queue(), catalog("paper")
    with_runs = {s.experiment for s in specs.values()}
    # every experiment with runs of its own is queued, the factorial's two seeds first, each run once
    assert with_runs - {e for e, _, _ in PAPER_QUEUE} == set() and "planning" in EXPERIMENTS
    assert queue[:12] == ["VFX@0", "VF@0", "V@0", "VX_t@0", "VX_p@0", "VX@0",
                          "VFX@1", "VF@1", "V@1", "VX_t@1", "VX_p@1", "VX@1"]
    assert len(queue) == len(set(queue)) and all(t in specs for t in queue)
    firsts = {}
    for t in queue:
        firsts.setdefault(specs[t].experiment, queue.index(t))
    assert [e for e, _ in sorted(firsts.items(), key=lambda x: x[1])] == list(
        dict.fromkeys(e for e, _, _ in PAPER_QUEUE if e in firsts))
    with pytest.raises(ConfigError, match="not a run"):
        ap.lease_commands({"queue": ["VFX@0", "rm -rf /"], "resume_from": []}, "c0ffee")


@pytest.mark.slow
def test_one_allocation_trains_and_measures_a_run_of_every_experiment(tmp_path):
    """The queue at the tiny preset: the first run of every experiment in one allocation, each finished; the
    factorial's measured as the device measures it (ridge), every other experiment's completely (MLP probes and the
    untrained bound too), and the merge reports every experiment's section."""
    import os
    import subprocess
    import sys

    from pokeworld.remote.queue import catalog, paper_queue

    specs, firsts = catalog("tiny"), {}
    for t in paper_queue("tiny"):
        firsts.setdefault(specs[t].experiment, t)
    out, work = tmp_path / "out", tmp_path / "work"
    env = {**os.environ, "PYTHON": sys.executable, "ALLOC_PRESET": "tiny", "ALLOC_STEPS": "10", "ALLOC_TESTS": "0",
           "ALLOC_BUDGET_MIN": "30", "ALLOC_WORK": str(work), "PYTHONPATH": str(ROOT / "src")}
    proc = subprocess.run(["bash", "scripts/gpu_allocation.sh", str(out), *firsts.values()], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=1200)
    assert proc.returncode == 0, proc.stdout[-3000:]
    (tmp_path / "scratch").mkdir()
    [a] = allocations.open_allocations([out], tmp_path / "scratch")
    assert sorted(a.progress["finished"]) == sorted(specs[t].name for t in firsts.values())
    for exp, t in firsts.items():
        [path] = (work / "map" / "runs" / specs[t].name).glob("measure*.json")  # measure-<corpus>.json elsewhere
        measured = json.loads(path.read_text())
        assert ("mlp" in measured["probes"]) == (exp != "factorial"), exp
        assert (measured.get("untrained") is not None) == (exp != "factorial"), exp
    merged = allocations.merge_allocations([a])
    assert set(merged["experiments"]) >= set(firsts)


def _copied(root, folders):
    """The plan's folders to resume from and its copy lines, the lines run in a real bash at ``root``."""
    import subprocess

    paths, copies = ap.device_folders(folders, root=root)
    for line in copies:
        subprocess.run(["/bin/bash", "-c", line], cwd=root, check=True, timeout=30)
    return paths, copies


def _files(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_a_later_plans_copy_never_nests_in_an_earlier_one_and_alloc_resume_names_it(tmp_path, monkeypatch):
    # a lease returns into out/returned; a plan copies it into .resume/; the lease's next command returns more into
    # the same folder, and the next plan must copy that, not nest it in the earlier copy nor name the earlier copy
    root = tmp_path / "repo"
    (root / ".git" / "info").mkdir(parents=True)
    returned = tmp_path / "out" / "returned"
    (returned / "parts").mkdir(parents=True)
    (returned / "records.tar.gz").write_bytes(b"first")
    assert _copied(root, [str(returned)])[0] == [".resume/returned"]
    assert _files(root / ".resume" / "returned") == _files(returned)
    # the same return planned again: its copy is there already, nothing to copy, the same folder named
    assert ap.device_folders([str(returned)], root=root) == ([".resume/returned"], [])
    (returned / "records.tar.gz").write_bytes(b"second")
    (returned / "parts" / "part-000").write_bytes(b"weights")
    paths, copies = _copied(root, [str(returned)])
    assert paths == [".resume/returned-2"]
    assert _files(root / ".resume" / "returned-2") == _files(returned)  # exactly the return the plan read
    assert _files(root / ".resume" / "returned") == {"records.tar.gz": b"first"}  # the earlier copy kept as it was
    # the copy lines run twice (pasted again): the same files in the same folder, nothing nested
    import subprocess

    for line in copies:
        subprocess.run(["/bin/bash", "-c", line], cwd=root, check=True, timeout=30)
    assert _files(root / ".resume" / "returned-2") == _files(returned)
    # the printed plan: ALLOC_RESUME and the carried paths name the copy of this return
    monkeypatch.chdir(root)
    p = {"configuration": "k", "commits": [], "corpora": [], "finished": [], "other_configurations": {},
         "queue": ["V@0"], "resume": {"V@0": {"step": 5, "from": str(returned)}}, "resume_from": [str(returned)]}
    start = next(x for x in ap.plan_lines(p, "abc1234") if "gpu_lease.sh start" in x)
    env = shlex.split(start.split(" && ")[-1])[1]
    assert split_folder_list(env.split("=", 1)[1]) == [".resume/returned-2"]


def test_a_planted_folder_under_the_resume_name_is_never_copied_into(tmp_path):
    # a folder of other files (or a link) where the plan would copy: another name, the folder left as it is
    root = tmp_path / "repo"
    (root / ".git" / "info").mkdir(parents=True)
    (root / ".resume" / "returned").mkdir(parents=True)
    (root / ".resume" / "returned" / "mine").write_text("mine")
    (root / ".resume" / "returned-2").symlink_to(tmp_path)
    returned = tmp_path / "elsewhere" / "returned"
    returned.mkdir(parents=True)
    (returned / "records.tar.gz").write_bytes(b"r")
    paths, _ = _copied(root, [str(returned)])
    assert paths == [".resume/returned-3"] and _files(root / ".resume" / "returned-3") == _files(returned)
    assert _files(root / ".resume" / "returned") == {"mine": b"mine"}


def test_a_leases_share_of_the_queue_fits_a_device_command():
    names = [f"VFX-h1-4-16-lam0.02-standard-{'x' * 150}-s{i}" for i in range(20)]
    head = "x" * 300
    share = ap.lease_share(names, head)
    assert 0 < len(share) < ap.LEASE_SHARE and share == names[:len(share)]
    assert len(" ".join([head, *share])) <= ap.MAX_COMMAND < len(" ".join([head, *names[:len(share) + 1]]))
    assert ap.lease_share(["VFX@0"] * 40, head) == ["VFX@0"] * ap.LEASE_SHARE
