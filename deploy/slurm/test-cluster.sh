#!/usr/bin/env bash
# Runs the job files in this folder, unchanged, on a real one-node Slurm cluster started here:
# munged, slurmctld and slurmd in a temporary folder, stopped again on exit, also on failure.
#
# It checks what a studio relies on:
#   - precompute-shard.sbatch as a 4-element array, and precompute-merge.sbatch after it, give
#     the same bytes as one `precompute` on one machine;
#   - an element cancelled with scancel while its precompute runs leaves nothing in the parts
#     folder, the afterok merge is never released, a merge run anyway fails naming the missing
#     part, and resubmitting that one element (--array=K) completes the set;
#   - synth-frames.sbatch as a 3-element array over a 6-frame sequence gives the same bytes, frame
#     for frame, as one `spreadlet synth --frames` on one machine.
#
# Needs Debian's slurm-wlm and munge (slurmctld, slurmd, sbatch, munged) and the binaries
# precompute, spreadlet and spreadlet-scene in SPREADLET_BIN (default: target/release).
# Environment:
#   SPREADLET_BIN            folder of the binaries
#   SPREADLET_CACHE          database cache for synth (default: a folder in the temporary one)
#   SPREADLET_SLURM_TIMEOUT  seconds any one wait may take (default 300)
#   SPREADLET_SLURM_KEEP=1   keep the temporary folder (logs, configuration) for a look
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(cd "$here/../.." && pwd)"
export SPREADLET_BIN="${SPREADLET_BIN:-$repo/target/release}"
timeout_s="${SPREADLET_SLURM_TIMEOUT:-300}"
started_at=$SECONDS

say() { echo "[slurm-test $((SECONDS - started_at))s] $*"; }
die() {
  echo "slurm cluster test FAILED: $*" >&2
  exit 1
}

for tool in munged munge unmunge slurmctld slurmd sbatch squeue scontrol scancel sinfo; do
  command -v "$tool" >/dev/null 2>&1 || [ -x "/usr/sbin/$tool" ] ||
    die "$tool is not installed (Debian: apt-get install slurm-wlm munge)"
done
sbin() { if command -v "$1" >/dev/null 2>&1; then command -v "$1"; else echo "/usr/sbin/$1"; fi; }
for bin in precompute spreadlet spreadlet-scene; do
  [ -x "$SPREADLET_BIN/$bin" ] || die "$SPREADLET_BIN/$bin is missing (cargo build --release)"
done

work="$(mktemp -d "${TMPDIR:-/tmp}/spreadlet-slurm.XXXXXX")"
chmod 755 "$work"
conf="$work/slurm.conf"
daemon_pids=()
daemon_names=()

# Stops every job, then every daemon this script started (newest first), then any job step
# (slurmstepd) of this cluster still alive; shows the logs when the test failed.
cleanup() {
  local status=$?
  trap - EXIT INT TERM
  set +e
  # Only a running slurmctld can cancel jobs; asking a dead one would wait out client timeouts.
  local controller_alive=0 i
  for i in "${!daemon_pids[@]}"; do
    if [ "${daemon_names[i]}" = slurmctld ] && kill -0 "${daemon_pids[i]}" 2>/dev/null; then
      controller_alive=1
    fi
  done
  if [ "$controller_alive" = 1 ]; then
    SLURM_CONF="$conf" scancel --quiet --user="$(id -un)" 2>/dev/null
    local until=$((SECONDS + 15))
    while [ -n "$(SLURM_CONF="$conf" squeue -h -o %i 2>/dev/null)" ] && [ $SECONDS -lt $until ]; do
      sleep 0.5
    done
  fi
  for ((i = ${#daemon_pids[@]} - 1; i >= 0; i--)); do
    kill "${daemon_pids[i]}" 2>/dev/null
  done
  local until=$((SECONDS + 15))
  for pid in "${daemon_pids[@]}"; do
    while kill -0 "$pid" 2>/dev/null && [ $SECONDS -lt $until ]; do sleep 0.2; done
    kill -9 "$pid" 2>/dev/null
    wait "$pid" 2>/dev/null
  done
  # slurmstepd leaves slurmd's process tree; it carries this cluster's SLURM_CONF.
  for pid in $(pgrep -x slurmstepd 2>/dev/null); do
    if { tr '\0' '\n' <"/proc/$pid/environ"; } 2>/dev/null | grep -qxF "SLURM_CONF=$conf"; then
      kill -9 "$pid" 2>/dev/null
    fi
  done
  if [ "$status" -ne 0 ]; then
    for log in "$work"/log/*.log "$work"/run/*.out; do
      [ -f "$log" ] || continue
      echo "----- ${log#"$work"/} (last 40 lines)" >&2
      tail -n 40 "$log" >&2
    done
  fi
  if [ "${SPREADLET_SLURM_KEEP:-0}" = 1 ]; then
    echo "kept $work" >&2
  else
    rm -rf "$work"
  fi
  exit "$status"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

# Fails at once, with the daemon's own words, when a daemon this script started has exited:
# waiting out the timeout would only hide why Slurm cannot run here.
daemons_alive() {
  local i
  for i in "${!daemon_pids[@]}"; do
    if ! kill -0 "${daemon_pids[i]}" 2>/dev/null; then
      local log="$work/log/${daemon_names[i]}.log"
      die "${daemon_names[i]} exited; last lines of its log: $(tail -n 5 "$log" 2>/dev/null)"
    fi
  done
}

# Waits until `$@` succeeds, for at most timeout_s; `what` says what is awaited.
wait_until() {
  local what="$1"
  shift
  local until=$((SECONDS + timeout_s))
  until "$@" >/dev/null 2>&1; do
    daemons_alive
    [ $SECONDS -lt $until ] || die "timed out after ${timeout_s}s waiting for $what"
    sleep 0.2
  done
}

# Two free TCP ports next to each other, so a second run (or a real Slurm) on this machine does
# not collide with this one.
listening_ports() { ss -Hltn 2>/dev/null | awk '{print $4}' | sed 's/.*://' | sort -u; }
port=""
for _ in $(seq 50); do
  candidate=$((20000 + RANDOM % 20000))
  if ! listening_ports | grep -qxE "$candidate|$((candidate + 1))"; then
    port=$candidate
    break
  fi
done
[ -n "$port" ] || die "found no free pair of TCP ports"

mkdir -p "$work"/{munge-key,munge-socket,log,state,spool,run,parts}
chmod 700 "$work/munge-key"
chmod 755 "$work/munge-socket"

say "starting munged"
head -c 1024 /dev/urandom >"$work/munge-key/munge.key"
chmod 400 "$work/munge-key/munge.key"
socket="$work/munge-socket/munge.socket"
# --force: munged refuses to run as root, or with its key in a temporary folder, without it.
"$(sbin munged)" --foreground --force --socket="$socket" \
  --key-file="$work/munge-key/munge.key" --log-file="$work/log/munged.log" \
  --pid-file="$work/munge-socket/munged.pid" --seed-file="$work/munge-key/munged.seed" \
  >>"$work/log/munged.log" 2>&1 &
daemon_pids+=($!)
daemon_names+=(munged)
munge_roundtrip() { munge --socket="$socket" -n | unmunge --socket="$socket"; }
wait_until "munged to answer on $socket" munge_roundtrip

node="$(hostname -s)"
user="$(id -un)"
cpus="$(nproc)"
# proctrack/linuxproc and task/none: no cgroups needed, which containers and CI machines often
# do not delegate. No accounting database: job states come from slurmctld (MinJobAge keeps
# finished jobs visible for the length of the test).
cat >"$conf" <<EOF
ClusterName=spreadlet-test
SlurmctldHost=$node(127.0.0.1)
SlurmctldPort=$port
SlurmdPort=$((port + 1))
SlurmUser=$user
SlurmdUser=$user
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$socket
StateSaveLocation=$work/state
SlurmdSpoolDir=$work/spool
SlurmctldPidFile=$work/slurmctld.pid
SlurmdPidFile=$work/slurmd.pid
SlurmctldLogFile=$work/log/slurmctld.log
SlurmdLogFile=$work/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
SchedulerType=sched/backfill
MpiDefault=none
MailProg=/bin/true
ReturnToService=2
KillWait=5
MinJobAge=3600
NodeName=$node NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=1000 State=UNKNOWN
PartitionName=test Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF="$conf"

say "starting slurmctld and slurmd ($node, $cpus CPUs, ports $port-$((port + 1)))"
"$(sbin slurmctld)" -D -f "$conf" >>"$work/log/slurmctld.log" 2>&1 &
daemon_pids+=($!)
daemon_names+=(slurmctld)
wait_until "slurmctld to answer (scontrol ping)" scontrol ping
"$(sbin slurmd)" -D -f "$conf" -N "$node" >>"$work/log/slurmd.log" 2>&1 &
daemon_pids+=($!)
daemon_names+=(slurmd)
node_idle() { sinfo -h -n "$node" -o %T | grep -qx idle; }
wait_until "node $node to be idle in sinfo" node_idle

# Job states, one "INDEX STATE" line per array element (or "- STATE" for a plain job).
job_states() {
  scontrol show job -o "$1" |
    awk '{ idx = "-"; st = "?";
           for (i = 1; i <= NF; i++) {
             if ($i ~ /^ArrayTaskId=/) { idx = substr($i, 13) }
             if ($i ~ /^JobState=/) { st = substr($i, 10) } }
           print idx, st }' | sort -n
}
# True once none of the given jobs is pending, running or completing.
jobs_done() { [ -z "$(squeue -h -j "$(IFS=,; echo "$*")" -o %i 2>/dev/null)" ]; }
wait_for_jobs() { wait_until "jobs $* to finish" jobs_done "$@"; }
# The names in a folder, sorted, on one line.
listing() { find "$1" -mindepth 1 -maxdepth 1 -printf '%f\n' | sort | tr '\n' ' '; }
expect_states() {
  local job="$1" want="$2" got
  got="$(job_states "$job" | tr '\n' ' ' | sed 's/ $//')"
  [ "$got" = "$want" ] || die "job $job: expected states '$want', got '$got'"
}

cd "$work/run"
model=physical-lens
profile="test"
seed=3
# 96 PSFs instead of the test profile's few: a part then takes seconds, so the element below is
# cancelled while its precompute runs, not before it starts or after it is done.
precompute_args="--psfs 96"
shards=4
export SPREADLET_MODEL=$model SPREADLET_PROFILE=$profile SPREADLET_SEED=$seed
export SPREADLET_SHARDS=$shards SPREADLET_PRECOMPUTE_ARGS="$precompute_args"
export SPREADLET_PARTS_DIR="$work/parts"
export SPREADLET_CACHE="${SPREADLET_CACHE:-$work/cache}"

say "single-machine reference database"
# shellcheck disable=SC2086
"$SPREADLET_BIN/precompute" --model $model --profile $profile --seed $seed $precompute_args \
  --out "$work/reference.sprdlt" 2>"$work/log/reference-precompute.log"

say "precompute array of $shards; element 2 is cancelled while it runs"
export SPREADLET_DB="$work/merged.sprdlt"
array=$(sbatch --parsable --array=0-$((shards - 1)) "$here/precompute-shard.sbatch")
# The merge as docs/BATCH.md submits it: held until every element has succeeded.
held_merge=$(sbatch --parsable --dependency=afterok:"$array" "$here/precompute-merge.sbatch")
element_log="$work/run/spreadlet-precompute-${array}_2.out"
element_started() { grep -q "shard index 2 from SLURM_ARRAY_TASK_ID" "$element_log"; }
element_queued() { [ -n "$(squeue -h -j "${array}_2" -o %i 2>/dev/null)" ]; }
started_or_over() { element_started || ! element_queued; }
wait_until "array element ${array}_2 to start precompute" started_or_over
element_started ||
  die "element 2 ended without precompute reporting 'shard index 2 from SLURM_ARRAY_TASK_ID'"
scancel "${array}_2"
wait_for_jobs "$array"
if [ "$(job_states "$array" | awk '$1 == 2 {print $2}')" = COMPLETED ]; then
  die "element 2 finished before scancel reached it: give the parts more work (--psfs)"
fi
expect_states "$array" "0 COMPLETED 1 COMPLETED 2 CANCELLED 3 COMPLETED"
parts_left="$(listing "$work/parts")"
[ "$parts_left" = "part-0.sprdlt part-1.sprdlt part-3.sprdlt report-0.json report-1.json report-3.json " ] ||
  die "the cancelled element left output behind, or a part is missing: parts/ holds $parts_left"

never_released() {
  [ "$(squeue -h -j "$held_merge" -o '%T %r')" = "PENDING DependencyNeverSatisfied" ]
}
wait_until "the afterok merge to be marked DependencyNeverSatisfied" never_released
scancel "$held_merge"

say "the merge refuses the set without part 2"
refused=$(sbatch --parsable "$here/precompute-merge.sbatch")
wait_for_jobs "$refused"
expect_states "$refused" "- FAILED"
grep -q "missing part(s) 2/4" "spreadlet-merge-$refused.out" ||
  die "the refused merge does not name the missing part 2/4: $(grep -m1 . "spreadlet-merge-$refused.out")"
[ ! -e "$SPREADLET_DB" ] || die "the refused merge wrote $SPREADLET_DB"

say "resubmitting element 2, merge after it"
resubmitted=$(sbatch --parsable --array=2 "$here/precompute-shard.sbatch")
merge=$(sbatch --parsable --dependency=afterok:"$resubmitted" "$here/precompute-merge.sbatch")
wait_for_jobs "$resubmitted" "$merge"
expect_states "$resubmitted" "2 COMPLETED"
expect_states "$merge" "- COMPLETED"
cmp "$work/reference.sprdlt" "$SPREADLET_DB" ||
  die "the merged database differs from the single-machine build"
# Written atomically: no temporary (hidden) file may be left anywhere.
stray="$(find "$work/parts" "$work" -maxdepth 1 -name '.*' | tr '\n' ' ')"
[ -z "$stray" ] || die "temporary files were left behind: $stray"

say "rendering a 6-frame sequence of the crossing scene"
mkdir -p "$work/shot/gbuffer"
for frame in 1 2 3 4 5 6; do
  # A different seed per frame (anti-aliasing jitter), so that frames differ and a frame
  # written under the wrong number would show.
  "$SPREADLET_BIN/spreadlet-scene" render crossing --width 48 --aa 4 --seed "$frame" --quiet \
    --gbuffer "$work/shot/gbuffer/$(printf %04d "$frame").exr" \
    --camera-out "$work/shot/camera.json" >>"$work/log/render.log" 2>&1
done
synth_args="--backend cpu --db-profile test"
mkdir -p "$work/shot/reference"
# shellcheck disable=SC2086
"$SPREADLET_BIN/spreadlet" synth --input "$work/shot/gbuffer/####.exr" --frames 1-6 \
  --camera "$work/shot/camera.json" --out "$work/shot/reference/####.exr" --quiet $synth_args \
  2>"$work/log/reference-synth.log"

say "synth array of 3 over frames 1-6"
synth=$(SPREADLET_INPUT="$work/shot/gbuffer/####.exr" SPREADLET_OUTPUT="$work/shot/dof/####.exr" \
  SPREADLET_CAMERA="$work/shot/camera.json" SPREADLET_FRAMES=1-6 SPREADLET_SHARDS=3 \
  SPREADLET_SYNTH_ARGS="$synth_args" \
  sbatch --parsable --array=0-2 "$here/synth-frames.sbatch")
wait_for_jobs "$synth"
expect_states "$synth" "0 COMPLETED 1 COMPLETED 2 COMPLETED"
frames_written="$(listing "$work/shot/dof")"
[ "$frames_written" = "0001.exr 0002.exr 0003.exr 0004.exr 0005.exr 0006.exr " ] ||
  die "the synth array wrote $frames_written, not frames 0001-0006"
for frame in 0001 0002 0003 0004 0005 0006; do
  cmp "$work/shot/reference/$frame.exr" "$work/shot/dof/$frame.exr" ||
    die "frame $frame from the array differs from the single-machine run"
done
# Equal frames would also come from elements that each did the whole range: every element's
# log must show its own two frames (one summary line per frame).
for k in 0 1 2; do
  count="$(grep -c "synthesis" "spreadlet-synth-${synth}_$k.out" || true)"
  [ "$count" = 2 ] ||
    die "element $k synthesised $count frames, not its share of 2: $(cat "spreadlet-synth-${synth}_$k.out")"
done
stray="$(find "$work/shot/dof" -name '.*' | tr '\n' ' ')"
[ -z "$stray" ] || die "temporary files were left behind: $stray"
say "passed: sharded precompute, cancel and resubmit, refused merge, frame ranges"
