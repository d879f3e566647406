#!/usr/bin/env bash
# A throwaway single-node SLURM on this machine, to run an sbatch file for real (CI-optional: not
# part of `make test`). Needs root and Debian's slurmctld, slurmd and munge packages (--install
# installs them with apt-get).
#
#   scripts/slurm_local.sh --install                 # the smoke job: Ray via `ray symmetric-run` under srun
#   scripts/slurm_local.sh pipelines/slurm/render.sbatch --trajectory trajectory/latest --workers 2
#   SBATCH_ARGS="--cpus-per-task=2" scripts/slurm_local.sh pipelines/slurm/render.sbatch ...
#   scripts/slurm_local.sh --keep ...                # leave the daemons running (stop: --down)
#   scripts/slurm_local.sh --down
#
# It writes slurm.conf for this host (`slurmd -C`: its CPUs and memory) under $SLURM_LOCAL_DIR
# (default /tmp/nsim-slurm; SLURM_CONF points there, /etc/slurm is not touched), starts munged,
# slurmctld and slurmd, submits the sbatch file from the repository root with `sbatch --wait`,
# prints the job's output and exits with the job's exit code. It stops only the daemons it started.
set -euo pipefail

REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
STATE=${SLURM_LOCAL_DIR:-/tmp/nsim-slurm}
export SLURM_CONF="$STATE/slurm.conf"
INSTALL=0
KEEP=0

log() { echo "slurm_local: $*" >&2; }
die() { log "$*"; exit 2; }

stop_daemons() {
    local name pidfile pid
    for name in slurmd slurmctld munged; do
        pidfile="$STATE/$name.pid"
        [[ -f "$pidfile" ]] || continue
        pid=$(cat "$pidfile")
        if [[ -n "$pid" ]] && kill -0 "$pid" 2>/dev/null; then
            kill "$pid"
            for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
        fi
        rm -f "$pidfile"
    done
}

while [[ $# -gt 0 ]]; do
    case "$1" in
        --install) INSTALL=1; shift ;;
        --keep) KEEP=1; shift ;;
        --down) stop_daemons; log "stopped"; exit 0 ;;
        -h|--help) sed -n '2,16p' "$0"; exit 0 ;;
        *) break ;;
    esac
done

[[ $(id -u) -eq 0 ]] || die "must run as root (it starts slurmctld, slurmd and munged)"
if ! command -v slurmctld >/dev/null || ! command -v slurmd >/dev/null || ! command -v munged >/dev/null \
    || ! command -v sbatch >/dev/null; then
    [[ $INSTALL -eq 1 ]] || die "slurmctld/slurmd/munge are not installed; rerun with --install (apt-get)"
    log "installing slurmctld slurmd slurm-client munge"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurmctld slurmd slurm-client munge >/dev/null
fi

stop_daemons  # a previous --keep run
mkdir -p "$STATE"/{ctld,spool,log,munge,jobs}
chmod 755 "$STATE"
NODE=$(hostname -s)
START=$(date +%s.%N)

# --- munge: a key for this machine, a private socket
if [[ ! -s /etc/munge/munge.key ]]; then
    mkdir -p /etc/munge
    dd if=/dev/urandom of=/etc/munge/munge.key bs=1 count=1024 status=none
fi
chown munge:munge /etc/munge/munge.key "$STATE/munge" 2>/dev/null || true
chmod 400 /etc/munge/munge.key
mkdir -p /run/munge /var/log/munge /var/lib/munge
chown munge:munge /run/munge /var/log/munge /var/lib/munge 2>/dev/null || true
if ! munge -n </dev/null 2>/dev/null | unmunge >/dev/null 2>&1; then
    if id munge >/dev/null 2>&1; then
        runuser -u munge -- munged --pid-file="$STATE/munge/munged.pid"
    else
        munged --force --pid-file="$STATE/munge/munged.pid"
    fi
    cp "$STATE/munge/munged.pid" "$STATE/munged.pid"
    for _ in $(seq 50); do munge -n </dev/null 2>/dev/null | unmunge >/dev/null 2>&1 && break; sleep 0.1; done
fi
munge -n </dev/null | unmunge >/dev/null || die "munged does not answer"

# --- slurm.conf for this host: its real CPUs, sockets and memory as slurmd sees them
HW=$(slurmd -C | head -n 1 | sed -e 's/ UpTime=.*//')
[[ "$HW" == NodeName=* ]] || die "slurmd -C gave: $HW"
cat >"$SLURM_CONF" <<EOF
ClusterName=nsimlocal
SlurmctldHost=$NODE
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
StateSaveLocation=$STATE/ctld
SlurmdSpoolDir=$STATE/spool
SlurmctldPidFile=$STATE/slurmctld.pid
SlurmdPidFile=$STATE/slurmd.pid
SlurmctldLogFile=$STATE/log/slurmctld.log
SlurmdLogFile=$STATE/log/slurmd.log
SlurmctldPort=${SLURM_LOCAL_CTLD_PORT:-6817}
SlurmdPort=${SLURM_LOCAL_SLURMD_PORT:-6818}
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
MpiDefault=none
ReturnToService=2
SchedulerType=sched/backfill
$HW State=UNKNOWN
PartitionName=local Nodes=$NODE Default=YES MaxTime=INFINITE State=UP OverSubscribe=NO
EOF

# --- the daemons (each daemonises and writes its pid file)
slurmctld -f "$SLURM_CONF"
slurmd -f "$SLURM_CONF" -N "$NODE"
if [[ $KEEP -eq 0 ]]; then trap stop_daemons EXIT; fi
for _ in $(seq 100); do
    state=$(sinfo -h -N -o '%T' 2>/dev/null | head -n 1 || true)
    [[ "$state" == idle* ]] && break
    sleep 0.2
done
[[ "$state" == idle* ]] || { tail -n 20 "$STATE"/log/*.log >&2; die "node $NODE is '${state:-unknown}', not idle"; }
log "up in $(awk "BEGIN{printf \"%.1f\", $(date +%s.%N) - $START}") s: $(sinfo -h -N -o '%N %T cpus=%c mem=%mMB')"

# --- the job: the given sbatch file, or the smoke job
if [[ $# -gt 0 ]]; then
    JOB_FILE=$1
    shift
else
    JOB_FILE="$STATE/jobs/smoke.sbatch"
    cat >"$JOB_FILE" <<'EOF'
#!/bin/bash
#SBATCH --job-name=nsim-smoke
#SBATCH --nodes=1
#SBATCH --ntasks-per-node=1
# Ray under SLURM the way pipelines/slurm/render.sbatch starts it, with a Python driver instead of nsim.
set -euo pipefail
export PATH="$SLURM_SUBMIT_DIR/.venv/bin:$PATH" RAY_AUTH_MODE=token
RAY_AUTH_TOKEN=$(python -c 'import secrets; print(secrets.token_hex(32))')
export RAY_AUTH_TOKEN
HEAD=$(scontrol show hostnames "$SLURM_JOB_NODELIST" | head -n 1)
HEAD_IP=$(srun --nodes=1 --ntasks=1 -w "$HEAD" hostname --ip-address | awk '{print $1}')
CPUS=${SLURM_CPUS_PER_TASK:-$(nproc)}
srun --nodes="$SLURM_JOB_NUM_NODES" --ntasks-per-node=1 \
    ray symmetric-run --address "$HEAD_IP:${RAY_PORT:-6379}" --min-nodes "$SLURM_JOB_NUM_NODES" \
        --num-cpus "$CPUS" --include-dashboard false -- \
    python -c "
import sys, ray
from nsim.distributed import map_tasks
ray.init(address='$HEAD_IP:${RAY_PORT:-6379}')
nodes = [n for n in ray.nodes() if n['Alive']]
print('ray', ray.__version__, 'nodes', len(nodes), 'CPUs', ray.cluster_resources().get('CPU'))
ray.shutdown()
out = map_tasks(abs, [-1, -2, -3], engine='ray', address='$HEAD_IP:${RAY_PORT:-6379}')
print('map_tasks on the cluster:', out)
sys.exit(0 if out == [1, 2, 3] else 1)
"
EOF
fi
[[ -f "$JOB_FILE" ]] || die "$JOB_FILE: no such sbatch file"
OUT="$STATE/jobs/job-%j.out"
cd "$REPO"
log "sbatch ${SBATCH_ARGS:-} $JOB_FILE $*"
set +e
# shellcheck disable=SC2086
SUBMIT=$(sbatch --parsable --wait --output="$OUT" ${SBATCH_ARGS:-} "$JOB_FILE" "$@")
RC=$?
set -e
JOB_ID=${SUBMIT%%;*}
log "job $JOB_ID finished with exit code $RC; its output:"
cat "${OUT/\%j/$JOB_ID}" 2>/dev/null || log "(no output file)"
exit "$RC"
