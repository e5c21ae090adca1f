"""Whether the kernel SocketCAN tests can run here: AF_CAN and the vcan interfaces they use.

On the development and CI machines the kernel has no AF_CAN, so these tests skip with one reason;
``make test-vcan`` runs them under a Linux kernel that has vcan (tests/vcan/run_vm.sh). On a normal
Linux host: ``sudo ip link add dev vcan0 type vcan && sudo ip link set up vcan0`` (and vcan1, vcan2).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from benchtwin.chain.transports.socketcan import af_can_unavailable_reason

#: the interfaces the vcan tests use: the back-to-back suite's two buses, the paper setup's three
VCAN_IFACES = ("vcan0", "vcan1", "vcan2")


def vcan_unavailable_reason(ifaces: tuple[str, ...] = VCAN_IFACES) -> str | None:
    """``None`` when raw CAN sockets work and every interface of ``ifaces`` exists, else one line why not."""
    reason = af_can_unavailable_reason()
    if reason is not None:
        return f"{reason}; `make test-vcan` runs these tests under a kernel with vcan"
    missing = [i for i in ifaces if not Path("/sys/class/net", i).exists()]
    if missing:
        return (f"no {', '.join(missing)} here (create with `ip link add dev {missing[0]} type vcan` "
                f"and `ip link set up {missing[0]}`)")
    return None


def skip_without_vcan(ifaces: tuple[str, ...] = VCAN_IFACES) -> None:
    """Skip the calling test with the one reason of :func:`vcan_unavailable_reason`."""
    reason = vcan_unavailable_reason(ifaces)
    if reason is not None:
        pytest.skip(reason)


#: the part of the paper setup's quick campaign the socketcan round trip plays (plant seconds): 2 s of the
#: electric half-pedal acceleration, about 5,300 frames on three buses, thermo PDOs and Modbus polls. The
#: whole campaign is 2.5 million frames: hours for a software-emulated guest, whose Python moves a few
#: hundred frames per second
QUICK_SLICE = ("quick", 240.0, 242.0)
#: the environment variable naming a directory where the slice's Trace was saved beforehand (by
#: tests/vcan/run_vm.sh on the host, where simulating the campaign takes seconds, not the guest's minutes)
TRACE_ENV = "BENCHTWIN_VCAN_TRACE"


def save_quick_slice(directory: str | Path) -> Path:
    """Simulate the quick campaign on the shipped vehicle and save the :data:`QUICK_SLICE` of its Trace."""
    from benchtwin.config.campaign import load_campaign
    from benchtwin.config.vehicle import load_vehicle
    from benchtwin.emulator import simulate_campaign

    name, start, end = QUICK_SLICE
    trace = simulate_campaign(load_vehicle(None), load_campaign(f"{name}.toml"))
    trace.slice_time(start, end).save(directory)
    return Path(directory)


def quick_slice_dir(tmp_dir: Path) -> Path:
    """The saved slice: the one named by ``$BENCHTWIN_VCAN_TRACE`` if there is one, else simulated now."""
    import os

    given = os.environ.get(TRACE_ENV, "")
    if given and (Path(given) / "trace.mf4").exists():
        return Path(given)
    return save_quick_slice(tmp_dir / "quick_slice")


def quick_campaign_seed() -> int:
    """The sensor seed ``benchtwin serve --campaign quick`` would encode with (the campaign's own)."""
    from benchtwin.config.campaign import load_campaign

    return int(load_campaign(f"{QUICK_SLICE[0]}.toml").seed or 0)
