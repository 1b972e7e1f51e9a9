#!/usr/bin/env bash
# `make test-slurm` (issue 23): the Slurm path end to end on a real one-node cluster on this machine.
#  1. slurm-wlm and munge from apt (installed when missing and we are root; otherwise says what to run);
#  2. munged, slurmctld and slurmd started with a generated config in a temporary folder (ports 6917/6918, so an
#     existing cluster is left alone), this host as the only node;
#  3. ci-textured simulated, `msnerf partition --blocks 2x2 --slurm` (no GPU gres on a CPU node), `sbatch` of the
#     job array; task 1 is requeued by `scontrol requeue` once it is training: it gets SIGTERM, saves, and its second
#     start resumes from the checkpoint (the task's log shows both starts, the block's steps end at the target);
#  4. `msnerf export pointcloud BLOCKS` merges the four blocks.
# The daemons are stopped at the end, whatever happened. Usage: tools/test-slurm.sh [STEPS] (~5 min at 300 steps on
# 2 cores with lavapipe).
set -euo pipefail
cd "$(dirname "$0")/.."
steps="${1:-300}"
bin="$(pwd)/target/release/msnerf"
[ -x "$bin" ] || { echo "test-slurm: build first (make build)" >&2; exit 1; }
need=()
for c in sbatch slurmctld slurmd munged; do command -v "$c" > /dev/null || need+=("$c"); done
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ]; then
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q slurm-wlm munge > /dev/null
  else
    echo "test-slurm: missing ${need[*]}: run  sudo apt-get install -y slurm-wlm munge  and again as root" >&2
    exit 1
  fi
fi
[ "$(id -u)" = 0 ] || { echo "test-slurm: the one-node cluster's daemons run as root: run as root" >&2; exit 1; }

work="$(mktemp -d /tmp/msnerf-slurm.XXXXXX)"
host="$(hostname -s)"
conf="$work/slurm.conf"
mkdir -p "$work"/{state,spool,log}
cat > "$conf" << EOF
ClusterName=msnerf-test
SlurmctldHost=$host
SlurmctldPort=6917
SlurmdPort=6918
SlurmUser=root
AuthType=auth/munge
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
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=none
ReturnToService=2
KillWait=60
NodeName=$host CPUs=$(nproc) RealMemory=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 1024 )) State=UNKNOWN
PartitionName=test Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF="$conf"
cleanup() {
  [ -f "$work/slurmd.pid" ] && kill "$(cat "$work/slurmd.pid")" 2> /dev/null || true
  [ -f "$work/slurmctld.pid" ] && kill "$(cat "$work/slurmctld.pid")" 2> /dev/null || true
  sleep 1
  rm -rf "$work"
}
trap cleanup EXIT
if ! pgrep -x munged > /dev/null; then
  mkdir -p /run/munge && chown munge:munge /run/munge
  [ -f /etc/munge/munge.key ] || { dd if=/dev/urandom of=/etc/munge/munge.key bs=1024 count=1 status=none; chown munge:munge /etc/munge/munge.key; chmod 400 /etc/munge/munge.key; }
  runuser -u munge -- /usr/sbin/munged
fi
slurmctld -f "$conf"
slurmd -f "$conf"
for _ in $(seq 30); do sinfo -h -o %T 2> /dev/null | grep -q idle && break; sleep 1; done
sinfo

start=$(date +%s)
"$bin" simulate --scene ci-textured --out "$work/data" > /dev/null
"$bin" partition "$work/data" --blocks 2x2 --overlap 0.2 --out "$work/blocks" --slurm --slurm-gres none \
  --slurm-cpus 1 --slurm-time 00:30:00 --host-budget-gib 1 -- --model tiny --max-steps "$steps" --rays-per-batch 1024
job=$(sbatch --parsable "$work/blocks/slurm.sh")
echo "submitted job array $job"
# Requeue task 1 once it is training (its metrics are being written).
metrics="$work/blocks/block_1_0/run/metrics.jsonl"
for _ in $(seq 600); do [ -s "$metrics" ] && [ "$(wc -l < "$metrics")" -ge 20 ] && break; sleep 1; done
[ -s "$metrics" ] || { echo "test-slurm: task 1 never started training" >&2; cat "$work"/blocks/slurm-*.log >&2 || true; exit 1; }
before=$(wc -l < "$metrics")
scontrol requeue "${job}_1"
echo "requeued task 1 after $before logged steps"
for _ in $(seq 1800); do [ -z "$(squeue -h -j "$job" 2> /dev/null)" ] && break; sleep 1; done
[ -z "$(squeue -h -j "$job")" ] || { echo "test-slurm: the array did not finish" >&2; squeue >&2; exit 1; }
fail=0
for b in block_0_0 block_1_0 block_0_1 block_1_1; do
  s="$work/blocks/$b/run/summary.json"
  if [ ! -f "$s" ] || ! grep -q "\"steps\": $steps," "$s"; then echo "test-slurm: $b did not finish $steps steps" >&2; fail=1; fi
done
log1=$(ls "$work"/blocks/slurm-"${job}"_1.log)
starts=$(grep -c "^run folder:" "$log1" || true)
grep -q "interrupted (SIGINT or SIGTERM)" "$log1" || { echo "test-slurm: task 1's first start did not stop on SIGTERM" >&2; fail=1; }
[ "$starts" -ge 2 ] || { echo "test-slurm: task 1 ran $starts time(s), 2 expected (requeued)" >&2; fail=1; }
first_step=$(grep -o '"step":[0-9]*' "$metrics" | head -1)
restarts=$(grep -c '"step":0,' "$metrics" || true)
[ "$restarts" -le 1 ] || { echo "test-slurm: task 1 started over after the requeue ($restarts starts at step 0)" >&2; fail=1; }
cat "$log1"
"$bin" export pointcloud "$work/blocks" --out "$work/merged.ply" --rays 20000
[ -s "$work/merged.ply" ] || { echo "test-slurm: no merged cloud" >&2; fail=1; }
echo "test-slurm: $(( $(date +%s) - start )) s from simulation to merged cloud; first logged $first_step; result $([ $fail = 0 ] && echo PASS || echo FAIL)"
exit $fail
