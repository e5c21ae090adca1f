#!/usr/bin/env bash
# `make test-vcan`: run the tests marked `vcan` (kernel SocketCAN on vcan0..vcan2) under a Linux kernel
# that has CAN, on a machine whose own kernel has none (socket(AF_CAN) -> errno 97).
#
# Debian's kernel (linux-image-amd64, with vcan.ko) boots under QEMU with software emulation (no KVM)
# through virtme-ng, which shares this machine's root filesystem read-only with the guest, so the
# project's .venv runs there unchanged; tests/vcan/run_in_guest.sh creates the interfaces and runs one
# pytest process. The guest has no network.
#
# Exit status: 0 and one "SKIPPED" line where this machine cannot boot a guest (not root, packages or
# virtme-ng cannot be installed, QEMU does not start); otherwise the guest's pytest status (a failing
# test fails the step), 124 if the guest run exceeds VCAN_TIMEOUT seconds. VCAN_K: a pytest -k expression
# to run only some of the vcan tests.
set -uo pipefail
cd "$(dirname "$0")/../.."
ROOT=$PWD
VCAN_TIMEOUT=${VCAN_TIMEOUT:-1200}
VNG_VENV=${VNG_VENV:-$ROOT/.venv-vng}
PY=$ROOT/.venv/bin/python
T0=$(date +%s)
now() { date +%s; }
skip() { echo "test-vcan: SKIPPED: $*"; exit 0; }

[ "$(id -u)" = 0 ] || skip "needs root (package installs, and modprobe/ip in the guest)"
[ -x "$PY" ] || { echo "test-vcan: no $PY (make .venv/.installed first)" >&2; exit 2; }
WORK=$(mktemp -d "${TMPDIR:-/tmp}/benchtwin-vcan.XXXXXX") || skip "no scratch directory"
trap 'rm -rf "$WORK"' EXIT

# 1. Debian packages: QEMU, the kernel, a static busybox (virtme-ng's initramfs), can-utils (candump/cansend)
t=$(now)
export DEBIAN_FRONTEND=noninteractive
apt-get update -q >"$WORK/apt.log" 2>&1 || skip "apt-get update failed (see a local run for details)"
apt-get install -y -q --no-install-recommends qemu-system-x86 linux-image-amd64 busybox-static can-utils \
    >>"$WORK/apt.log" 2>&1 || skip "apt-get install of qemu-system-x86 linux-image-amd64 busybox-static can-utils failed"
T_APT=$(( $(now) - t ))

# 2. virtme-ng in its own small venv (its commands call each other: its bin goes on PATH)
t=$(now)
if [ ! -x "$VNG_VENV/bin/vng" ]; then
    { python3 -m venv "$VNG_VENV" && "$VNG_VENV/bin/pip" install -q virtme-ng; } >"$WORK/pip.log" 2>&1 \
        || skip "cannot install virtme-ng from PyPI"
fi
export PATH="$VNG_VENV/bin:$PATH"
T_VNG=$(( $(now) - t ))
KVER=$(ls /lib/modules | grep -- '-amd64$' | sort -V | tail -1)
KIMG=/boot/vmlinuz-$KVER
[ -n "$KVER" ] && [ -r "$KIMG" ] && [ -e "/lib/modules/$KVER/kernel/drivers/net/can/vcan.ko" ] \
    || skip "no Debian kernel with vcan.ko under /boot and /lib/modules"

# 3. The project venv as an ext4 image (a block device the guest caches; the 9p root is uncached and
#    imports from it are slower). Optional: without mkfs.ext4 the guest reads .venv over 9p.
t=$(now)
DRIVE=()
if command -v mkfs.ext4 >/dev/null; then
    size_mb=$(( $(du -sm .venv | cut -f1) * 13 / 10 + 200 ))
    if truncate -s "${size_mb}M" "$WORK/venv.img" && mkfs.ext4 -q -F -d .venv "$WORK/venv.img" >"$WORK/mkfs.log" 2>&1
    then
        DRIVE=(--qemu-opts="-drive file=$WORK/venv.img,format=raw,if=virtio,readonly=on")
    fi
fi
T_IMG=$(( $(now) - t ))

# 4. What the guest would be slowest at, done here: numba's machine code for a generic x86-64 CPU (the
#    guest's emulated CPU is not this one; compiling under emulation takes many minutes), and the slice of
#    the quick campaign the round trip plays (tests/chain/live/vcan_env.py), handed over in an env file
t=$(now)
cat >"$WORK/guest.env" <<ENV
export NUMBA_CPU_NAME=generic NUMBA_CACHE_DIR=$WORK/numba BENCHTWIN_VCAN_TRACE=$WORK/quick_slice
export VCAN_K='${VCAN_K:-}'
ENV
(. "$WORK/guest.env" && PYTHONPATH=tests/chain/live "$PY" -c "
import vcan_env
from benchtwin.chain.acquisition import acquire
from benchtwin.chain.batch import deliver
from benchtwin.config.setup import load_setup
from benchtwin.sensors import encode
from benchtwin.trace import Trace
d = vcan_env.save_quick_slice('$WORK/quick_slice')
setup = load_setup('paper')
acquire(deliver(encode(Trace.load(d), setup, seed=vcan_env.quick_campaign_seed()), setup), setup)
") >"$WORK/prepare.log" 2>&1 || { cat "$WORK/prepare.log" >&2; echo "test-vcan: FAILED: preparing the run" >&2; exit 1; }
T_PREP=$(( $(now) - t ))

# 5. Boot the guest and run the tests (software emulation; the guest command's status comes back)
t=$(now)
timeout "$VCAN_TIMEOUT" vng --run "$KIMG" --disable-kvm --user root -m 2G --cpus 2 "${DRIVE[@]}" \
    --exec "$ROOT/tests/vcan/run_in_guest.sh $WORK/guest.env" 2>&1 | tee "$WORK/guest.log"
rc=${PIPESTATUS[0]}
T_VM=$(( $(now) - t ))
if ! grep -q "^vcan-guest: up" "$WORK/guest.log"; then
    [ "$rc" = 124 ] && skip "the guest did not come up within $VCAN_TIMEOUT s"
    skip "the guest did not boot (vng exit $rc)"
fi
echo "test-vcan: apt ${T_APT} s, virtme-ng ${T_VNG} s, venv image ${T_IMG} s, preparation ${T_PREP} s," \
     "guest (boot + tests) ${T_VM} s," \
     "total $(( $(now) - T0 )) s; guest exit $rc"
[ "$rc" = 124 ] && echo "test-vcan: FAILED: the guest run exceeded $VCAN_TIMEOUT s" >&2
exit "$rc"
