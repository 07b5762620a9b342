"""GPU allocations of the paper-budget map, checked on a CPU at the tiny preset: scripts/gpu_allocation.sh end to end
(training mode and bench mode), and the merge of allocations (scripts/merge_allocations.py) into one record naming
each run's device and date and reading its returned weights. A killed allocation and its resumption:
tests/test_allocation_crash.py."""

import json
import os
import shutil
import subprocess
import sys
import tarfile
from datetime import datetime
from pathlib import Path

import pytest
import torch

from pokeworld import certify, experiments as experiment
from pokeworld.errors import ConfigError
from pokeworld.experiments.record import record_problem
from pokeworld.remote import allocations
from pokeworld.remote.pack import check_return_folder, read_stream
from pokeworld.record_paths import placeholder
from pokeworld.rundir import load_model

ROOT = Path(__file__).resolve().parents[1]
V, VFX, VX_t = (f"{v}-h1-4-16-lam0.02-standard-s0" for v in ("V", "VFX", "VX_t"))


@pytest.fixture(scope="module")
def allocation_a(tmp_path_factory):
    """The allocation script's default (training) mode at the tiny preset on this CPU, two runs (the smoke check
    skips without a GPU)."""
    base = tmp_path_factory.mktemp("alloc")
    out, work = base / "A", base / "A_work"
    env = {**os.environ, "PYTHON": sys.executable, "ALLOC_PRESET": "tiny", "ALLOC_BUDGET_MIN": "5",
           "ALLOC_WORK": str(work), "ALLOC_COMMIT": "abc1234"}
    proc = subprocess.run(["bash", "scripts/gpu_allocation.sh", str(out), "V", "VFX"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return out, work


@pytest.fixture(scope="module")
def allocation_b(tmp_path_factory):
    """A second allocation (VFX again, and VX_t) as a bare pack whose device.json names another device, a day later."""
    base = tmp_path_factory.mktemp("alloc_b")
    work = base / "map"
    work.mkdir()
    (work / "device.json").write_text(json.dumps({"device": "NVIDIA H200", "date": "2099-01-02T00:00:00+00:00",
                                                  "torch": "2.11.0+cu130", "git": "abc1234"}))
    pack = base / "map_tiny.tar.gz"
    experiment.run(experiment.make_config("tiny", out=str(work), variants=("VFX", "VX_t"), certify=False,
                                          workers=1, pack=str(pack)))
    return pack


def _merge(tmp_path, *args):
    out = tmp_path / "merged" / "map_paper.json"
    allocations.main([*map(str, args), "--out", str(out), "--markdown", str(out.with_suffix(".md"))])
    return json.loads(out.read_text()), out.with_suffix(".md").read_text()


def _unpacked(pack: Path, dest: Path) -> Path:
    with tarfile.open(pack) as tar:
        tar.extractall(dest, filter="data")
    return dest


@pytest.mark.slow
def test_the_allocation_script_runs_end_to_end_and_brings_back_small_files(allocation_a, tmp_path):
    out, work = allocation_a
    files = sorted(p.name for p in out.iterdir())
    assert files == [".pokeworld-owned", "allocation.log", "device.json", "pack.tar.part00", "records.tar.gz"]
    assert check_return_folder(out) == []  # at most 8 files, none over 16 MiB
    device = json.loads((out / "device.json").read_text())
    assert device["device"].startswith("cpu") and datetime.fromisoformat(device["date"]) and device["torch"]
    assert device["git"] == "abc1234"  # ALLOC_COMMIT: the device's copy has no .git
    log = (out / "allocation.log").read_text()
    assert "smoke check exit status 0" in log and "benchmark" not in log
    with tarfile.open(out / "records.tar.gz") as tar:
        names = set(tar.getnames())
    assert {"device.json", "progress.json", "map_config.json", "data/standard/manifest.json", "returned.json",
            f"runs/{V}/measure.json", f"runs/{VFX}/metrics.jsonl"} <= names
    # no certificates computed, no checkpoint or data among the records
    assert not any(n.endswith(("certificates.json", ".pt", ".h5")) for n in names)
    assert not (work / "map" / "data" / "standard" / "certificates.json").exists()
    # the final weights of both runs came back in the parts, and load
    assert sorted((m.run, m.kind) for m in read_stream(out)) == [(V, "final"), (VFX, "final")]
    a = allocations.open_allocation(out, tmp_path)
    assert a.weights == {V: "returned", VFX: "returned"} and a.checkpoints == {}
    model = load_model(a.root / "runs" / VFX)
    trained = load_model(work / "map" / "runs" / VFX)
    for (k, x), y in zip(model.state_dict().items(), trained.state_dict().values()):
        assert x.dtype == y.dtype and torch.allclose(x, y, rtol=1e-2, atol=1e-6), k  # large tensors: bfloat16
    cfg = json.loads((work / "map" / "map_config.json").read_text())
    assert cfg["variants"] == ["V", "VFX"] and not cfg["certify"] and not cfg["mlp_probes"]
    assert cfg["time_budget_min"] > 0


@pytest.mark.slow
def test_bench_mode_runs_the_full_cuda_tests_and_the_benchmark_and_trains_nothing(tmp_path):
    out = tmp_path / "bench"
    env = {**os.environ, "PYTHON": sys.executable, "ALLOC_MODE": "bench", "ALLOC_BENCH_PRESETS": "tiny",
           "ALLOC_BENCH_CONFIGS": "fast", "ALLOC_BENCH_STEPS": "2", "ALLOC_WORK": str(tmp_path / "work")}
    proc = subprocess.run(["bash", "scripts/gpu_allocation.sh", str(out)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    files = sorted(p.name for p in out.iterdir())
    assert files == [".pokeworld-owned", "allocation.log", "bench.json", "cuda_tests.log", "device.json"]
    bench = json.loads((out / "bench.json").read_text())["results"]
    assert [(r["preset"], r["config"]) for r in bench] == [("tiny", "fast")] and bench[0]["sec_per_step"] > 0
    assert "exit status" in (out / "cuda_tests.log").read_text()
    assert not (tmp_path / "work" / "map" / "runs").exists()


@pytest.mark.slow
def test_the_merge_names_each_runs_device_and_date_and_keeps_a_run_trained_twice_once(allocation_a, allocation_b,
                                                                                      tmp_path):
    out, _ = allocation_a
    merged, md = _merge(tmp_path, allocation_b, out, "--runs-out", tmp_path / "runs")  # dates decide the order
    assert record_problem(merged) is None  # a results record: merge_map_results.py and the report read it
    assert set(merged["runs"]) == {V, VFX, VX_t} and merged["experiments"]["factorial"]
    assert merged["map_config"]["variants"] == ["V", "VX_t", "VFX"]  # the paper's order
    a_device = json.loads((out / "device.json").read_text())
    assert merged["runs"][V]["allocation"]["device"] == a_device["device"]
    assert merged["runs"][V]["allocation"]["date"] == a_device["date"]
    assert merged["runs"][V]["allocation"]["weights"] == "returned"
    # the kept runs whose weights came back (VFX is kept from the later allocation, a bare pack without weights)
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == [V]
    assert load_model(tmp_path / "runs" / V).state_dict()  # a run folder the CPU side can probe
    for name in (VFX, VX_t):  # the later allocation's
        assert merged["runs"][name]["allocation"]["weights"] == "not returned"  # a bare pack of records
        assert merged["runs"][name]["allocation"]["device"] == "NVIDIA H200"
        assert merged["runs"][name]["allocation"]["date"].startswith("2099-01-02")
        assert merged["runs"][name]["allocation"]["steps_trained"] == 10
    [dup] = merged["provenance"]["duplicates"]
    # the record names no machine's paths: each allocation's folder as a placeholder
    assert dup["run"] == VFX and dup["kept"] == placeholder(str(allocation_b)) and dup["dropped"] == placeholder(str(out))
    assert str(tmp_path) not in json.dumps(merged) and "/tmp/" not in md
    assert isinstance(dup["largest_ridge_difference"], float)
    assert [a["device"] for a in merged["provenance"]["allocations"]] == [a_device["device"], "NVIDIA H200"]
    assert len(merged["provenance"]["corpus_sha256"]) == 64
    row = next(line for line in md.splitlines() if line.startswith(f"| {VFX} |"))
    assert "NVIDIA H200" in row and "2099-01-02" in row and "/ +0.49" in row  # the paper's log k beside ours
    assert f"`{VFX}` was trained in two allocations" in md
    assert (tmp_path / "merged" / "map_paper.png").exists()


@pytest.mark.slow
def test_the_merge_refuses_another_corpus_or_other_settings(allocation_a, allocation_b, tmp_path):
    out, _ = allocation_a
    other = _unpacked(allocation_b, tmp_path / "other")
    manifest = other / "data" / "standard" / "manifest.json"
    m = json.loads(manifest.read_text())
    manifest.write_text(json.dumps({**m, "content_sha256": "0" * 64}))
    with pytest.raises(SystemExit, match="000000000000.*share the seeded corpus"):
        allocations.main([str(out), str(other), "--out", str(tmp_path / "m.json")])
    assert not (tmp_path / "m.json").exists()
    manifest.write_text(json.dumps(m))
    cfg_path = other / "map_config.json"
    cfg_path.write_text(json.dumps({**json.loads(cfg_path.read_text()), "train_steps": 20000}))
    with pytest.raises(SystemExit, match="other settings.*train_steps"):
        allocations.main([str(out), str(other), "--out", str(tmp_path / "m.json")])
    bad = tmp_path / "bad.tar.gz"
    bad.write_bytes(b"not a tar")
    with pytest.raises(SystemExit, match="not a map pack"):
        allocations.main([str(bad), "--out", str(tmp_path / "m.json")])


@pytest.mark.slow
def test_certificates_come_from_a_certify_json_of_the_same_corpus(allocation_a, tmp_path):
    out, work = allocation_a
    cert = certify.run(certify.make_config("tiny", data=str(work / "map" / "data" / "standard"),
                                           estimators=("linear", "drag"), out=str(tmp_path / "cert.json")))
    merged, md = _merge(tmp_path, out, "--certificates", cert)
    assert set(merged["certificates"]) == {"standard"} and merged["certificates"]["standard"]["gate"]
    assert "Recoverability certificates" in md and "Certificates: from a CPU-side certify JSON" in md
    c = json.loads(Path(cert).read_text())
    c["dataset"]["content_sha256"] = "f" * 64
    Path(cert).write_text(json.dumps(c))
    with pytest.raises(SystemExit, match="certifies corpus ffffffffffff"):
        _merge(tmp_path, out, "--certificates", cert)


@pytest.mark.slow
def test_a_run_the_budget_cut_short_is_named_not_counted(allocation_a, tmp_path):
    out, _ = allocation_a
    cut = _unpacked(out / "records.tar.gz", tmp_path / "cut")
    prog_path = cut / "progress.json"
    prog = json.loads(prog_path.read_text())
    prog_path.write_text(json.dumps({**prog, "finished": [VFX], "partial": {V: 5}, "complete": False}))
    merged, md = _merge(tmp_path, cut)
    assert set(merged["runs"]) == {VFX}
    assert merged["provenance"]["allocations"][0]["partial"] == {V: 5}
    assert f"{V} (step 5)" in md


def test_an_allocation_without_a_device_record_is_refused(allocation_b, tmp_path):
    bare = _unpacked(allocation_b, tmp_path / "bare")
    (bare / "device.json").unlink()
    with pytest.raises(ConfigError, match="device.json"):
        allocations.open_allocation(bare, tmp_path)
    folder = tmp_path / "returned"
    folder.mkdir()
    shutil.copy(allocation_b, folder)
    shutil.copy(allocation_b, folder / "second.tar.gz")
    with pytest.raises(ConfigError, match="one map pack"):
        allocations.open_allocation(folder, tmp_path)


def test_the_device_record_names_this_machine(tmp_path):
    rec = allocations.write_device(tmp_path / "sub" / "device.json")
    assert json.loads((tmp_path / "sub" / "device.json").read_text()) == rec
    assert rec["device"] and rec["torch"] and datetime.fromisoformat(rec["date"]).tzinfo is not None


def test_certify_off_cannot_certify_alongside():
    with pytest.raises(ConfigError, match="no-certify"):
        experiment.make_config("tiny", certify=False, certify_alongside=True)


def test_the_script_keeps_the_heavy_work_folder_out_of_what_comes_back(tmp_path):
    out = tmp_path / "out"
    env = {**os.environ, "PYTHON": sys.executable, "ALLOC_WORK": str(out / "work")}
    proc = subprocess.run(["bash", "scripts/gpu_allocation.sh", str(out)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2 and "must not lie inside OUT" in proc.stderr
    assert not out.exists()  # refused before anything was written


@pytest.mark.slow
def test_the_cpu_side_completes_the_returned_runs_and_the_merge_shows_it(allocation_a, tmp_path):
    """complete_allocations.py on a tiny allocation (cpu measurement preset: MLP probes and the untrained bound;
    small certificates; two planning episodes), then the merge with --cpu-side: every number with its machine."""
    out, _ = allocation_a
    work = tmp_path / "side"
    proc = subprocess.run([sys.executable, "scripts/complete_allocations.py", str(out), "--work", str(work),
                           "--preset", "cpu", "--certify-max-windows", "300", "--certify-fit-episodes", "0",
                           "--certify-epochs", "2", "--plan-episodes", "2"], cwd=ROOT, capture_output=True,
                          text=True, timeout=900, env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    stages = {json.loads(p.read_text())["stage"] for p in (work / "cpu_side").glob("*.json")
              if p.name != "machine.json"}
    assert stages == {f"measure {V}", f"measure {VFX}", "certify", "planning"}
    merged, md = _merge(tmp_path, out, "--cpu-side", work)
    for name in (V, VFX):
        run = merged["runs"][name]
        assert "contact" in run["probes"]["mlp"] and "log_k" in run["untrained"]["ridge"]["contact"]
        cpu = run["cpu_measurement"]
        assert cpu["device"].startswith("cpu") and datetime.fromisoformat(cpu["date"])
        # the same returned weights read on the same corpus: the CPU's ridge numbers are the device's, up to the
        # bfloat16 rounding of the trip and a different window cap
        assert isinstance(cpu["largest_ridge_difference"], float)
    assert merged["certificates"]["standard"]["settings"]["epochs"] == 2
    assert merged["planning"]["config"]["episodes"] == 2 and merged["planning"]["paper_budget"] is False
    assert "NOT the released planner's settings" in md and "Every number of each run" in md
    # a folder without its weight parts has no run to plan with: one line, not a random-only planning record
    bare = tmp_path / "bare"
    shutil.copytree(out, bare, ignore=shutil.ignore_patterns("pack.tar.part*"))
    proc = subprocess.run([sys.executable, "scripts/complete_allocations.py", str(bare), "--work", str(tmp_path / "w2"),
                           "--preset", "cpu", "--stages", "planning", "--plan-episodes", "2"], cwd=ROOT,
                          capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    assert proc.returncode != 0 and "no finished run with returned weights" in proc.stderr
    assert not (tmp_path / "w2" / "planning").exists()
    # the CPU side of another corpus is refused
    machine = work / "cpu_side" / "machine.json"
    m = json.loads(machine.read_text())
    machine.write_text(json.dumps({**m, "corpus": {**m["corpus"], "content_sha256": "0" * 64}}))
    with pytest.raises(SystemExit, match="another corpus"):
        _merge(tmp_path, out, "--cpu-side", work)


def test_a_record_of_another_corpus_is_kept_beside_the_new_one():
    old = {"provenance": {"corpus_sha256": "a" * 64}, "runs": {"VFX": {}}}
    new = {"provenance": {"corpus_sha256": "b" * 64}, "runs": {"VF": {}}}
    merged = allocations.carry_other_corpora(dict(new), old)
    assert merged["other_corpora"] == {"a" * 64: old} and merged["runs"] == {"VF": {}}
    again = allocations.carry_other_corpora({"provenance": {"corpus_sha256": "a" * 64}, "runs": {}}, merged)
    assert set(again["other_corpora"]) == {"b" * 64}  # the newer record of corpus a replaces the carried one
    assert allocations.carry_other_corpora(dict(new), {"provenance": {"corpus_sha256": "b" * 64}}) == new


def test_the_measurement_device_is_a_choice_every_job_carries(tmp_path):
    from pokeworld.experiments import stages

    c = experiment.make_config("tiny", out=str(tmp_path / "m"), variants=("VFX",), seeds=(0,), measure_device="cpu")
    job = stages.jobs(c, stages.all_specs(c), 0)[0]
    assert job["measure"]["device"] == "cpu" and job["measure"]["probe_device"] == "host"
    auto = experiment.make_config("tiny", out=str(tmp_path / "m"), variants=("VFX",), seeds=(0,))
    assert "device" not in stages.jobs(auto, stages.all_specs(auto), 0)[0]["measure"]
    with pytest.raises(ConfigError, match="measure_device"):
        experiment.make_config("tiny", measure_device="gpu2")


def test_a_probe_subset_names_its_corpus_and_keeps_only_probe_episodes(tiny_dataset, tmp_path):
    from pokeworld.data import load, read_manifest, save
    from pokeworld.remote.complete import probe_subset

    corpus = save(tiny_dataset, tmp_path / "corpus")
    sub = probe_subset(corpus, 5, tmp_path)
    ds, man = load(sub), read_manifest(sub)
    assert len(ds.episodes("probe_fit")) == 5 and len(ds.episodes("probe_test")) == 5 and ds.num_episodes == 10
    assert man["subset_of"]["content_sha256"] == read_manifest(corpus)["content_sha256"]
    picked = man["subset_of"]["episodes"]
    assert (ds.frames == tiny_dataset.frames[picked]).all()  # the corpus's own episodes, in corpus order
    assert probe_subset(corpus, 5, tmp_path) == sub  # reused
    too_many = len(tiny_dataset.episodes("probe_fit")) + 1
    with pytest.raises(ConfigError, match="probe_fit episodes"):
        probe_subset(corpus, too_many, tmp_path / "other")


def test_an_earlier_records_runs_of_the_same_corpus_are_carried_once_and_say_so():
    sha = "c" * 64
    alloc = lambda src, date: {"source": src, "device": "NVIDIA H200", "date": date}  # noqa: E731
    run = lambda v: {"train": {"variant": v, "seed": 0}}  # noqa: E731
    earlier = {"provenance": {"corpus_sha256": sha, "command": "merge A", "git": "aaa",
                              "allocations": [alloc("/work/x/lease-a", "d1")]},
               "runs": {"V-s0": run("V"), "VX-s0": run("VX")}, "experiments": {"factorial": ["V-s0", "VX-s0"]},
               "map_config": {}, "certificates": {"standard": {"gate": 1}}}
    new = {"provenance": {"corpus_sha256": sha, "command": "merge B", "git": "bbb",
                          "allocations": [alloc("leases/b", "d2")]},
           "runs": {"VX-s0": run("VX")}, "experiments": {"factorial": ["VX-s0"]}, "map_config": {}, "certificates": {}}
    once = allocations.carry_earlier_runs(new, earlier)
    assert set(once["runs"]) == {"V-s0", "VX-s0"} and once["runs"]["VX-s0"] is new["runs"]["VX-s0"]
    assert once["provenance"]["carried"] == {"runs": ["V-s0"], "command": "merge A", "git": "aaa"}
    assert [a["source"] for a in once["provenance"]["allocations"]] == ["lease-a (not given to this merge)", "leases/b"]
    assert once["certificates"] == earlier["certificates"] and once["map_config"]["variants"] == ["V", "VX"]
    # merged again from the same allocation: nothing twice, the first measuring command kept
    again = allocations.carry_earlier_runs(new, once)
    assert again["provenance"]["allocations"] == once["provenance"]["allocations"]
    assert again["provenance"]["carried"] == once["provenance"]["carried"]
    # another corpus's record is not carried here (carry_other_corpora keeps it apart)
    assert allocations.carry_earlier_runs(new, {**earlier, "provenance": {**earlier["provenance"],
                                                                          "corpus_sha256": "d" * 64}}) == new
