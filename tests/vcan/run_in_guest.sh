#!/bin/sh
# Runs inside the guest booted by tests/vcan/run_vm.sh (as root, the host's root filesystem shared
# read-only, writable overlays on /tmp, /etc, /var...; no network). Creates vcan0..vcan2, then runs
# every test marked `vcan` in ONE pytest process (each Python start costs about a minute here).
# Exit status: pytest's (vng hands it to the host).
# Argument: an env file from the host driver (numba cache, prepared trace), optional.
set -u
[ $# -ge 1 ] && [ -r "$1" ] && . "$1"
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
echo "vcan-guest: up, kernel $(uname -r), repo $ROOT"
t0=$(date +%s)
modprobe vcan || exit 90
for i in 0 1 2; do
    ip link add dev "vcan$i" type vcan && ip link set up "vcan$i" || exit 91
done
# vcan has no flow control: a slow receiver loses frames once its socket buffer is full (71 of 1000
# with the default 208 KiB under emulation); 16 MiB per socket holds every burst these tests send
# (and the per-CPU input backlog of the loopback path, 1000 packets by default)
sysctl -qw net.core.rmem_max=16777216 net.core.rmem_default=16777216 net.core.netdev_max_backlog=100000 || exit 92
# the project venv, as an ext4 image the host made (block device: cached by the guest, unlike the 9p
# root), mounted over its own path so that every path in it stays valid
if [ -e /dev/vda ] || modprobe -a virtio_blk ext4 2>/dev/null; then
    i=0; while [ ! -e /dev/vda ] && [ $i -lt 50 ]; do sleep 0.1; i=$((i+1)); done
    if [ -e /dev/vda ] && mount -o ro /dev/vda "$ROOT/.venv"; then
        echo "vcan-guest: .venv from the block image"
    fi
fi
ip -br link show type vcan
echo "vcan-guest: setup $(( $(date +%s) - t0 )) s"
cd "$ROOT" || exit 93
export HOME=/tmp PYTHONDONTWRITEBYTECODE=1 MPLCONFIGDIR=/tmp/vcan-mpl HYPOTHESIS_STORAGE_DIRECTORY=/tmp/vcan-hyp
export NUMBA_CACHE_DIR=${NUMBA_CACHE_DIR:-/tmp/vcan-numba}
export BENCHTWIN_EMULATED=1   # wall-clock pacing is not judged under software emulation
t1=$(date +%s)
.venv/bin/python -m pytest -p no:cacheprovider --basetemp=/tmp/vcan-pytest \
    -m vcan -v -rs --durations=0 --timeout=1500 ${VCAN_K:+-k "$VCAN_K"} \
    tests/chain/live/test_live_back2back.py tests/chain/live/test_live_vcan_tools.py \
    tests/chain/live/test_live_record_cli.py
rc=$?
echo "vcan-guest: pytest exit $rc after $(( $(date +%s) - t1 )) s"
exit $rc
