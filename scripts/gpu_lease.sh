#!/usr/bin/env bash
# A device lease as the unit of the paper-budget map (docs/model.md "GPU allocations: a lease"): the allocation
# (scripts/gpu_allocation.sh) runs detached for the whole lease, in its own session, so it survives between device
# commands, and each device command only collects its latest returned state into the command's output folder.
#
#   bash scripts/gpu_lease.sh start   OUT [RUNS...]  start the allocation detached (once per machine), then collect
#   bash scripts/gpu_lease.sh collect OUT            collect until the allocation ends or this command's time is up
#   bash scripts/gpu_lease.sh final   OUT            collect what the allocation returned last, now, and say whether
#                                                    it is still running
#
# The protocol for a 15-minute lease (three commands, each issued as soon as the previous returns, since a machine
# left idle for about half a minute is handed back): 1. start (returns after ALLOC_COLLECT_S, default 540 s);
# 2. collect (the same); 3. final. Every command's OUT holds the whole returned state of the lease so far (the files
# scripts/gpu_allocation.sh writes: allocation.log, device.json, .pokeworld-owned, records.tar.gz), copied whenever
# it changes, each file replaced atomically and the set copied again until no file changed during the copy, and the
# parts of the weights (pack.tar.part00..) that no earlier command of this lease returned, at most
# ALLOC_PARTS_PER_COMMAND of them, lowest first: a lease's weights take more than one return (a dozen paper runs are
# about 100 MiB, a return 64 MiB). Give scripts/merge_allocations.py every folder the lease returned: it joins them
# (the latest records, each part from whichever folder holds the bytes the latest index names).
#
# Environment (all optional; the allocation's own, ALLOC_PRESET, ALLOC_COMMIT, ALLOC_RESUME, ..., pass through):
#   ALLOC_LEASE_DIR    where the detached allocation lives on the machine (default /tmp/pokeworld-lease): a copy of
#                      this repository (so a later command's fresh copy never changes the files it runs), its work
#                      folder, its output folder, its pid
#   ALLOC_TESTS        the allocation's smoke check (default here 0: none; see below)
#   ALLOC_BUDGET_MIN   the allocation's budget, from its start to its last pack (default here 12: a 15-minute lease
#                      less the machine's start-up and the last collect)
#   ALLOC_COLLECT_S    seconds a start or collect command collects before it returns (default 540: under the
#                      10-minute limit of a device command, with room for the transfer)
#   ALLOC_POLL_S       seconds between looks at the allocation's output (default 5)
#   ALLOC_PARTS_PER_COMMAND  weight parts one command returns at most (default 4: beside the four small files, 8
#                      files and 64 MiB in all)
#   ALLOC_CONCURRENCY  most runs training at once (default here 8: the allocation measures how many pay)
#   ALLOC_RETURN_PARTS parts the weights may take in all (default here 12: three commands of four)
#   PYTHON             the interpreter (default python3)
set -uo pipefail
MODE=${1:?usage: bash scripts/gpu_lease.sh start|collect|final OUT [RUNS...]}
OUT=${2:?usage: bash scripts/gpu_lease.sh start|collect|final OUT [RUNS...]}
shift 2
LEASE=${ALLOC_LEASE_DIR:-/tmp/pokeworld-lease}
COLLECT_S=${ALLOC_COLLECT_S:-540}
POLL_S=${ALLOC_POLL_S:-5}
PER_COMMAND=${ALLOC_PARTS_PER_COMMAND:-4}
# the checkout is this script's own (scripts/ in it), whatever folder the command runs from
CHECKOUT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." 2>/dev/null && pwd) || CHECKOUT=""
if [ -z "$CHECKOUT" ] || [ ! -f "$CHECKOUT/scripts/gpu_allocation.sh" ] || [ ! -d "$CHECKOUT/src/pokeworld" ]; then
  echo "gpu_lease.sh must be run from a pokeworld checkout (scripts/gpu_lease.sh beside scripts/gpu_allocation.sh and src/pokeworld)" >&2
  exit 2
fi
STATE="$LEASE/out"
T0=$(date +%s)
say() { echo "[gpu_lease $MODE +$(( $(date +%s) - T0 ))s] $*"; }
case "$MODE" in start|collect|final) ;; *) echo "the mode must be start, collect or final, not $MODE" >&2; exit 2 ;; esac
case "$COLLECT_S$POLL_S$PER_COMMAND" in *[!0-9]*) echo "ALLOC_COLLECT_S, ALLOC_POLL_S and ALLOC_PARTS_PER_COMMAND must be whole numbers" >&2; exit 2 ;; esac
OUT=$(realpath -m "$OUT")
case "$LEASE/" in "$OUT"/*) echo "ALLOC_LEASE_DIR ($LEASE) must not lie inside OUT ($OUT)" >&2; exit 2 ;; esac
mkdir -p "$OUT" "$LEASE" || exit 2

running() {  # the detached allocation is alive (its pid, and that pid still runs the allocation script)
  local pid
  pid=$(cat "$LEASE/pid" 2>/dev/null) || return 1
  case "$pid" in ''|*[!0-9]*) return 1 ;; esac
  kill -0 "$pid" 2>/dev/null && tr '\0' ' ' <"/proc/$pid/cmdline" 2>/dev/null | grep -q gpu_allocation.sh
}

listing() { (cd "$STATE" 2>/dev/null && find . -maxdepth 1 -type f -printf '%f %s %T@\n' | sort); }

DELIVERED="$LEASE/delivered"  # "NAME SHA256" of each part an earlier command of this lease returned

wanted_parts() {  # the parts this command returns: the first PER_COMMAND whose bytes no earlier command returned
  local f name sha n=0
  for f in "$STATE"/pack.tar.part*; do
    [ -f "$f" ] && [ "$n" -lt "$PER_COMMAND" ] || continue
    name=$(basename "$f")
    sha=$(sha256sum "$f" | cut -d' ' -f1)
    grep -qxF "$name $sha" "$DELIVERED" 2>/dev/null && continue
    echo "$name"
    n=$((n + 1))
  done
}

copy_once() {  # the state's files into OUT, the weight parts first (the records name them), each replaced atomically
  local f name wanted
  wanted=$(wanted_parts)
  for name in $wanted; do
    cmp -s "$STATE/$name" "$OUT/$name" && continue
    cp -p "$STATE/$name" "$OUT/.incoming" && mv -f "$OUT/.incoming" "$OUT/$name" || return 1
  done
  for f in "$OUT"/pack.tar.part*; do  # a part earlier commands returned, or one the allocation no longer has
    [ -f "$f" ] || continue
    echo "$wanted" | grep -qxF "$(basename "$f")" || rm -f "$f"
  done
  for f in "$STATE"/records.tar.gz "$STATE"/device.json "$STATE"/.pokeworld-owned "$STATE"/allocation.log; do
    [ -f "$f" ] || continue
    name=$(basename "$f")
    cp -p "$f" "$OUT/.incoming" && mv -f "$OUT/.incoming" "$OUT/$name" || return 1
  done
  return 0
}

delivered() {  # this command's parts are what it returns: later commands return only parts with other bytes
  local f
  rm -f "$OUT/.incoming"
  for f in "$OUT"/pack.tar.part*; do
    [ -f "$f" ] && echo "$(basename "$f") $(sha256sum "$f" | cut -d' ' -f1)" >>"$DELIVERED"
  done
  say "returns $(find "$OUT" -maxdepth 1 -name 'pack.tar.part*' | wc -l) weight parts; $(awk 'END {print NR}' "$DELIVERED" 2>/dev/null || echo 0) returned by this lease in all"
}

COPIED=""
collect() {  # copy when the state changed, again until it did not change during the copy
  local before after try
  for try in 1 2 3 4 5; do
    before=$(listing; cat "$DELIVERED" 2>/dev/null)
    [ -n "$before" ] || return 0
    [ "$before" = "$COPIED" ] && return 0
    copy_once || { say "copy failed (try $try)"; sleep 1; continue; }
    after=$(listing; cat "$DELIVERED" 2>/dev/null)
    if [ "$before" = "$after" ]; then
      COPIED=$after
      say "collected: $(find "$OUT" -maxdepth 1 -type f | wc -l) files, $(du -sh "$OUT" | cut -f1)"
      return 0
    fi
  done
  say "the state kept changing during the copy; collected what was there"
}

if [ "$MODE" = start ]; then
  if running; then
    say "the allocation already runs (pid $(cat "$LEASE/pid")); collecting"
  elif [ -e "$LEASE/started" ]; then
    say "the allocation of this lease has ended; collecting what it returned (a new lease starts on a fresh machine)"
  else
    rm -rf "$LEASE/repo" && mkdir -p "$LEASE/repo" || exit 2
    cd "$CHECKOUT" || exit 2
    # a copy of the repository: the device replaces the command's folder with a fresh copy at each command. Only
    # the repository's own files: not .git nor what .gitignore names (a CPU dry-run's .venv is gigabytes; the device
    # installs its packages elsewhere), each .gitignore line a tar exclude (/x anchored at the root, x anywhere)
    EXCLUDES=(--exclude=./.git)
    while IFS= read -r pat; do
      pat=${pat%/}
      case "$pat" in ''|'#'*) ;; /*) EXCLUDES+=("--exclude=.$pat") ;; *) EXCLUDES+=("--exclude=$pat") ;; esac
    done < <(cat .gitignore 2>/dev/null)
    tar "${EXCLUDES[@]}" -cf - . | tar -xf - -C "$LEASE/repo" || exit 2
    # ALLOC_TESTS 0 by default in a lease: the smoke check's path (the reference form under CUDA graphs, trained,
    # resumed, measured) ran on the H200 lease of 2026-11-28 and every run records compiled and cudagraph_skips
    # itself; its minute is a fourth run's margin in 15 minutes (a plain gpu_allocation.sh keeps its smoke default)
    export PYTHONPATH="$LEASE/repo/src${PYTHONPATH:+:$PYTHONPATH}" ALLOC_BUDGET_MIN=${ALLOC_BUDGET_MIN:-12} \
      ALLOC_TESTS=${ALLOC_TESTS:-0} ALLOC_CONCURRENCY=${ALLOC_CONCURRENCY:-8} \
      ALLOC_RETURN_PARTS=${ALLOC_RETURN_PARTS:-12} \
      ALLOC_WORK=${ALLOC_WORK:-$LEASE/work}
    # the pid is written by the child itself, before it becomes the allocation: a kill of this command right
    # after the start cannot leave a running allocation without one
    (cd "$LEASE/repo" && echo "$BASHPID" >"$LEASE/pid" && exec setsid nohup bash scripts/gpu_allocation.sh \
      "$STATE" "$@" >"$LEASE/allocation.stdout" 2>&1 </dev/null) &
    sleep 1
    if ! running; then
      say "the allocation did not start: $(tail -n 3 "$LEASE/allocation.stdout" 2>/dev/null)"
      exit 3
    fi
    # marked started only once it runs: a start that failed leaves the next start free to try again
    date -u +%FT%TZ >"$LEASE/started"
    say "started the allocation detached (pid $(cat "$LEASE/pid"), budget $ALLOC_BUDGET_MIN min, at most $ALLOC_CONCURRENCY runs at once): runs ${*:-(the default queue)}"
  fi
fi

if [ "$MODE" = final ]; then
  collect
  delivered
  if running; then say "the allocation still runs (pid $(cat "$LEASE/pid")): what it returned so far is in OUT"
  else say "the allocation has ended: $(tail -n 1 "$STATE/allocation.log" 2>/dev/null)"; fi
  exit 0
fi

while :; do
  collect
  if ! running; then
    collect
    say "the allocation is not running: $(tail -n 1 "$STATE/allocation.log" 2>/dev/null)"
    break
  fi
  if [ $(( $(date +%s) - T0 )) -ge "$COLLECT_S" ]; then
    say "collected for ${COLLECT_S}s; the allocation still runs: issue the next command (collect, or final) now"
    break
  fi
  sleep "$POLL_S"
done
delivered
exit 0
