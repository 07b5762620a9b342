"""The next device lease, from what earlier allocations returned: its queue per environment configuration and the
exact commands whoever holds the device runs (``scripts/merge_allocations.py --plan``).

A record is one environment's: allocations are grouped by their **configuration key**, the first 12 hex digits of
the sha256 of the corpus generator's content config (the manifest's ``config``: physics, policy, ranges, seed,
episodes, splits), which decides the corpus bytes. The next lease trains this checkout's configuration (the key of
the ``paper`` map's corpus as this checkout would generate it): its runs that any allocation of the same key
finished are skipped, those with a returned checkpoint come first, then :func:`.queue.paper_queue` (the
factorial at seeds 0 and 1, VFX and VF first, then seed 2, then every other experiment of the paper, finding by
finding). Runs of other configurations (an earlier environment) are named
and never queued: they cannot be trained from this checkout.

Every word printed for a shell comes from a closed set or is checked: run tokens are re-made from a known variant
and an integer seed, or are run names of the map (:func:`.queue.parse_token`), the commit must be hexadecimal, and each folder to
resume from is quoted into ALLOC_RESUME's list and the list quoted for the shell (a folder with spaces stays one).
"""

from __future__ import annotations

import filecmp
import hashlib
import json
import os
import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import ConfigError
from ..io import parse_json
from ..sim.generate_config import content_config
from .queue import folder_list, order_queue, paper_queue, parse_token
from ..experiments.config import MapConfig
from ..experiments.presets import make_config
from ..experiments.stages import corpus_config

Key = str
"""A run's queue token: ``VARIANT@SEED`` for the factorial's, the run name for any other experiment's."""
COMMIT = re.compile(r"[0-9a-f]{4,40}")
#: What a device command runs first (docs/model.md "GPU allocations": the wheels carried in .whl).
SETUP = ("python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site "
         ".whl/*.whl && export PYTHONPATH=/tmp/site:$PWD/src PYTHONUNBUFFERED=1")


def configuration_key(config: dict) -> str:
    """The key of a corpus generator content config (a manifest's ``config``)."""
    return hashlib.sha256(json.dumps(config, sort_keys=True).encode()).hexdigest()[:12]


def checkout_configuration_of(c: MapConfig) -> str:
    """The configuration key of map ``c``'s standard corpus as this checkout generates it."""
    # through JSON, as a manifest stores it (tuples become lists)
    return configuration_key(parse_json(json.dumps(content_config(corpus_config(c, "standard"))).encode(),
                                        "<this checkout's corpus config>", "a corpus config"))


def checkout_configuration(preset: str = "paper") -> str:
    """:func:`checkout_configuration_of` the map's default config at ``preset``."""
    return checkout_configuration_of(make_config(preset))


@dataclass
class Returned:
    """What one allocation returned, as the plan needs it."""

    source: str
    configuration: str
    corpus_sha256: str
    git: str
    finished: set[Key] = field(default_factory=set)
    checkpoints: dict[Key, int] = field(default_factory=dict)


def queue_of(group: list[Returned], preset: str = "paper") -> dict:
    """The queue of one configuration (finished runs skipped, checkpoints first, then the paper's queue)."""
    finished: set[Key] = set().union(*(r.finished for r in group)) if group else set()
    ckpts: dict[Key, tuple[int, str]] = {}
    for r in group:
        for key, step in r.checkpoints.items():
            if step > ckpts.get(key, (-1, ""))[0]:
                ckpts[key] = (step, r.source)
    resumable = {k: v for k, v in ckpts.items() if k not in finished}
    requested = paper_queue(preset)
    requested += [k for k in resumable if k not in requested]  # a checkpoint outside the priority list resumes too
    queue = order_queue(requested, finished, set(resumable))
    return {"queue": list(queue), "finished": sorted(finished),
            "resume": {k: {"step": step, "from": src} for k, (step, src) in resumable.items()},
            "resume_from": sorted({src for _, src in resumable.values()}),
            "commits": sorted({r.git for r in group}), "corpora": sorted({r.corpus_sha256[:12] for r in group})}


def plan(returned: list[Returned], configuration: str) -> dict:
    """The next lease for ``configuration`` (this checkout's), and what the records hold of other configurations."""
    groups: dict[str, list[Returned]] = {}
    for r in returned:
        groups.setdefault(r.configuration, []).append(r)
    return {"configuration": configuration, **queue_of(groups.get(configuration, [])),
            "other_configurations": {k: {"finished": queue_of(g)["finished"], "corpora": queue_of(g)["corpora"],
                                         "commits": queue_of(g)["commits"]}
                                     for k, g in sorted(groups.items()) if k != configuration}}


def resume_value(folders: list[str]) -> str:
    """ALLOC_RESUME's value as a shell word: the folders as one list, each quoted for the list
    (:func:`.queue.folder_list`, read back by :func:`.queue.split_folder_list`), the list
    quoted again for the shell; a folder with spaces or quotes stays one folder."""
    return shlex.quote(folder_list(folders))


#: where each folder to resume from is copied before the lease: the device receives this checkout (tracked and
#: not-ignored files, and the ignored paths a call carries), nothing beside it, and gpu_lease.sh copies the checkout
#: without what .gitignore names (a folder under out/ would be carried and then left behind); this one is ignored
#: through .git/info/exclude only, so it travels both steps
RESUME_DIR = ".resume"


def same_files(a: Path, b: Path) -> bool:
    """Whether folders ``a`` and ``b`` hold the same regular files (relative names and bytes) and nothing else (no
    link, no other file, no extra folder): a copy in :data:`RESUME_DIR` the plan may name instead of copying again."""
    def listing(top: Path) -> dict[str, int] | None:
        found: dict[str, int] = {}
        for folder, dirs, files in os.walk(top):
            for name in dirs + files:
                path = Path(folder) / name
                if path.is_symlink() or not (path.is_dir() or path.is_file()):
                    return None
                if path.is_file():
                    found[str(path.relative_to(top))] = path.stat().st_size
        return found

    if not a.is_dir() or not b.is_dir() or a.is_symlink() or b.is_symlink():
        return False
    ours, theirs = listing(a), listing(b)
    return ours is not None and ours == theirs and all(filecmp.cmp(a / n, b / n, shallow=False) for n in ours)


def resume_destination(source: Path, home: Path, taken: set[str]) -> tuple[str, bool]:
    """Where a copy of ``source`` lies in ``home`` (:data:`RESUME_DIR`): ``NAME`` (``NAME-2``… when taken by
    another folder of this plan or holding other files: an earlier plan's copy of an older return, which is never
    copied into, nested in or replaced), and whether it must still be copied (False: it already holds exactly
    ``source``'s files, an earlier plan's copy of this return)."""
    base = source.name or "allocation"
    name, n = base, 1
    while True:
        dest = home / name
        if name not in taken:
            if not os.path.lexists(dest):
                return name, True
            if same_files(source, dest):
                return name, False
        n += 1
        name = f"{base}-{n}"


def device_folders(folders: list[str], root: Path | None = None) -> tuple[list[str], list[str]]:
    """Each folder to resume from as the device's copy of the checkout at ``root`` (default: the working directory,
    the repository root) sees it, and the shell lines that copy it into :data:`RESUME_DIR` first (ignored through
    .git/info/exclude, carried by the lease's commands). A folder already under ``.resume/`` stays where it is; any
    other is copied to a fresh ``.resume/NAME`` (:func:`resume_destination`), or named where an earlier plan copied
    it, so running the lines again, or after an earlier plan's, never nests a copy in an old one and ALLOC_RESUME
    names exactly the copy of the folder the plan read. Each copy line copies the folder's contents
    (``SRC/.``): run twice, it writes the same files into the same folder."""
    root = (root or Path.cwd()).resolve()
    home = root / RESUME_DIR
    paths, copies, taken = [], [], set()
    for f in folders:
        full = (root / f).resolve()
        if full.is_relative_to(home) and full != home:
            paths.append(str(full.relative_to(root)))
            taken.add(full.relative_to(home).parts[0])
            continue
        name, copy = resume_destination(full, home, taken)
        taken.add(name)
        paths.append(f"{RESUME_DIR}/{name}")
        if copy:
            copies.append(f"cp -r -- {shlex.quote(str(full) + '/.')} {shlex.quote(paths[-1])}")
    if copies:
        copies.insert(0, f"mkdir -p {RESUME_DIR} && (grep -qx '/{RESUME_DIR}/' .git/info/exclude 2>/dev/null "
                         f"|| echo '/{RESUME_DIR}/' >> .git/info/exclude)")
    return paths, copies


LEASE_SHARE = 16
"""Most runs a lease's start command names: more than a 15-minute lease trains (about five `paper` runs, at most a
dozen at the stacked rate hoped for), so that none of its time goes unused, and few enough for a device command."""
MAX_COMMAND = 2000
"""A device command's length limit (characters)."""


def lease_share(queue: list[str], head: str) -> list[str]:
    """The next lease's share of ``queue``: its first :data:`LEASE_SHARE` runs, fewer when the start command
    (``head`` and the runs) would pass :data:`MAX_COMMAND` characters."""
    share: list[str] = []
    for t in queue[:LEASE_SHARE]:
        if len(head) + sum(len(w) + 1 for w in share) + len(t) + 1 > MAX_COMMAND:
            break
        share.append(t)
    return share


def lease_commands(p: dict, commit: str) -> list[str]:
    """The three device commands of the next lease (docs/model.md "GPU allocations: a lease"), each a line; the
    start command names the lease's share of the queue (:func:`lease_share`)."""
    if not COMMIT.fullmatch(commit):
        raise ConfigError(f"the commit must be hexadecimal (4 to 40 digits), got {commit!r}; pass --commit SHA")
    runs = [shlex.quote(parse_token(t)) for t in p["queue"]]  # a known variant at an integer seed, or a run name
    folders = device_folders(p["resume_from"])[0]
    env = f"ALLOC_COMMIT={commit}" + (f" ALLOC_RESUME={resume_value(folders)}" if folders else "")
    head = f'{SETUP} && {env} bash scripts/gpu_lease.sh start "$OUT"'
    return [" ".join([head, *lease_share(runs, head)]),
            'bash scripts/gpu_lease.sh collect "$OUT"',
            'bash scripts/gpu_lease.sh final "$OUT"']


def plan_lines(p: dict, commit: str) -> list[str]:
    """The plan in words, then the commands of the next lease."""
    resume = " ".join(f"{t} (step {r['step']}, {r['from']})" for t, r in p["resume"].items())
    lines = [f"[plan] configuration {p['configuration']} (this checkout's paper corpus): earlier allocations ran "
             f"commits {', '.join(p['commits']) or 'none'} on corpora {', '.join(p['corpora']) or 'none'}; finished: "
             f"{' '.join(p['finished']) or 'none'}; checkpoints to resume: {resume or 'none'}"]
    for key, o in p["other_configurations"].items():
        lines.append(f"[plan] configuration {key} (another environment than this checkout's; not queued): corpora "
                     f"{', '.join(o['corpora'])}, commits {', '.join(o['commits'])}, "
                     f"finished {' '.join(o['finished'])}")
    lines.append(f"[plan] the queue, in this order ({len(p['queue'])} runs; the next lease takes the first ones the "
                 f"start command names): {' '.join(p['queue']) or 'nothing left'}")
    if not p["queue"]:
        return lines
    cmds = lease_commands(p, commit)
    folders, copies = device_folders(p["resume_from"])
    carry = ".whl" + "".join(f" {shlex.quote(f)}" for f in folders)
    if copies:  # the device receives this checkout only, and the lease copies it without what .gitignore names
        lines += ["[plan] first, here, in the repository root, copy the folders to resume from into the checkout "
                  "(the device receives only the checkout; the carried paths count towards its 64 MiB; a copy an "
                  "earlier plan made of other files is kept, and ALLOC_RESUME names this plan's: "
                  f"{' '.join(map(shlex.quote, folders))}):",
                  *copies]
    elif folders:
        lines.append("[plan] the folders to resume from are in the checkout already: "
                     f"{' '.join(map(shlex.quote, folders))}")
    return lines + [f"[plan] the lease: three device commands, each issued as soon as the previous returns "
                    f"(carry: {carry}; $OUT: the command's output folder)",
                    "# 1. start and collect (returns after 9 minutes):", cmds[0],
                    "# 2. collect, issued at once:", cmds[1], "# 3. final collect:", cmds[2]]


__all__ = ["RESUME_DIR", "device_folders", "resume_destination", "same_files",
           "configuration_key", "checkout_configuration_of", "checkout_configuration", "Returned", "queue_of", "plan",
           "resume_value", "lease_commands", "plan_lines", "SETUP"]
