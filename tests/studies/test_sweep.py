"""Sweeps: the local pool and a Dask cluster give one table, resume runs exactly the rest, a failing run is
recorded and the others complete, and the Trace cache serves the second sweep (no simulation).

Every sweep here is small: the quick campaign, 2 axes x 2 values, one seed, and only the battery family
(its constant-drive test through the chain and its identification), so a run takes well under a second
once the Trace is cached. The Trace is simulated once per session into a temporary cache.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from benchtwin.cli import main
from benchtwin.errors import ConfigError
from benchtwin.studies.sweep import Sweep, read_table
from benchtwin.studies.sweep_file import load_sweep

SWEEP = """
name = "test"
campaign = "quick"
seeds = [7]
families = ["battery"]

[axes]
setup.telemetry.k_tel = {k_tel}
setup.ivt.battery.current_errors.noise_std = [0.0, 0.5]
"""


def _file(tmp: Path, k_tel: str = "[500, 1000]", name: str = "sweep.toml") -> Path:
    p = tmp / name
    p.write_text(SWEEP.format(k_tel=k_tel), encoding="utf-8")
    return p


def _comparable(df: pd.DataFrame) -> pd.DataFrame:
    """The table without wall times and cache state, which differ between runs of the same sweep."""
    return df.drop(columns=["wall_s", "trace_cached"]).sort_values("run_key").reset_index(drop=True)


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("trace_cache")


@pytest.fixture(scope="module")
def serial_table(tmp_path_factory: pytest.TempPathFactory, cache: Path) -> pd.DataFrame:
    tmp = tmp_path_factory.mktemp("serial")
    outcome = Sweep.from_file(_file(tmp), cache_dir=cache).run(tmp / "out", workers=0, figures=False)
    assert outcome.done == 4 and outcome.failed == 0
    return read_table(tmp / "out")


def test_local_pool_and_dask_cluster_give_the_same_table(tmp_path: Path, cache: Path,
                                                         serial_table: pd.DataFrame) -> None:
    from distributed import LocalCluster

    sweep = Sweep.from_file(_file(tmp_path), cache_dir=cache)
    local = sweep.run(tmp_path / "local", workers=2)
    assert local.done == 4 and local.failed == 0
    assert {p.name for p in local.figures} == {"error_vs_setup.telemetry.k_tel.png",
                                               "error_vs_setup.ivt.battery.current_errors.noise_std.png",
                                               "pass_rate.png"}
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        dask = sweep.run(tmp_path / "dask", scheduler=cluster.scheduler_address, figures=False)
    assert dask.done == 4 and dask.failed == 0
    a, b = read_table(tmp_path / "local"), read_table(tmp_path / "dask")
    assert len(a) == 4 and a["run_key"].is_unique
    assert any(c.startswith("value:battery.") for c in a.columns)
    assert any(c.startswith("error:") for c in a.columns) and any(c.startswith("pass:") for c in a.columns)
    pd.testing.assert_frame_equal(_comparable(a), _comparable(b))
    pd.testing.assert_frame_equal(_comparable(a), _comparable(serial_table))
    parquet = pd.read_parquet(tmp_path / "local" / "runs.parquet")
    pd.testing.assert_frame_equal(_comparable(parquet), _comparable(a), check_dtype=False)


def test_resume_after_an_interruption_runs_exactly_the_rest(tmp_path: Path, cache: Path,
                                                            serial_table: pd.DataFrame) -> None:
    path = _file(tmp_path)
    first = Sweep.from_file(path, cache_dir=cache).run(tmp_path / "out", workers=0, max_runs=3, figures=False)
    assert (first.done, first.pending) == (3, 1)
    assert len(read_table(tmp_path / "out")) == 3
    assert (tmp_path / "out" / "runs.parquet").exists()  # written from what finished
    with pytest.raises(ConfigError, match="--resume"):
        Sweep.from_file(path, cache_dir=cache).run(tmp_path / "out", workers=0)
    rc = main(["sweep", str(path), "--out", str(tmp_path / "out"), "--resume", "--workers", "0",
               "--cache", str(cache), "--no-figures"])
    assert rc == 0
    lines = (tmp_path / "out" / "runs.csv").read_text(encoding="utf-8").splitlines()
    assert len(lines) == 1 + 4  # header + each run once
    pd.testing.assert_frame_equal(_comparable(read_table(tmp_path / "out")), _comparable(serial_table))
    again = Sweep.from_file(path, cache_dir=cache).run(tmp_path / "out", workers=0, resume=True, figures=False)
    assert (again.done, again.skipped) == (0, 4)


def test_a_run_that_raises_is_recorded_and_the_others_complete(tmp_path: Path, cache: Path) -> None:
    sweep = Sweep.from_file(_file(tmp_path, k_tel="[500, 333]"), cache_dir=cache)
    outcome = sweep.run(tmp_path / "out", workers=2, figures=True)
    assert (outcome.done, outcome.failed) == (2, 2)
    t = read_table(tmp_path / "out")
    bad = t[t["setup.telemetry.k_tel"] == 333]
    assert (bad["status"] == "failed").all()
    assert bad["error"].str.contains("k_tel 333 is not a switch position").all()
    assert bad["error"].str.contains("telemetry.k_tel").all()  # names the key
    good = t[t["setup.telemetry.k_tel"] == 500]
    assert (good["status"] == "ok").all() and (good["error"] == "").all() and good["n_checks"].gt(0).all()


def test_the_trace_cache_serves_the_second_sweep(tmp_path: Path, cache: Path) -> None:
    # a seed no other test uses: the first sweep simulates its Trace once, the second simulates nothing
    path = _file(tmp_path).read_text(encoding="utf-8").replace("seeds = [7]", "seeds = [11]")
    (tmp_path / "s.toml").write_text(path, encoding="utf-8")
    first = Sweep.from_file(tmp_path / "s.toml", cache_dir=cache).run(tmp_path / "a", workers=0, figures=False)
    second = Sweep.from_file(tmp_path / "s.toml", cache_dir=cache).run(tmp_path / "b", workers=0, figures=False)
    assert first.simulated == 1 and second.simulated == 0
    assert read_table(tmp_path / "b")["trace_cached"].all()


def test_sweep_file_errors_name_the_key_and_what_is_allowed(tmp_path: Path) -> None:
    p = tmp_path / "bad.toml"
    p.write_text('campaign = "quick"\nfamilies = ["batt"]\n[axes]\nsetup.telemetry.k_tl = [1]\n'
                 'setup.ivt.battery.current_errors.noise_std = {start = 0, stop = 1}\n', encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        load_sweep(p)
    msg = str(err.value)
    assert "families: unknown family 'batt'" in msg and "allowed: transmission" in msg
    assert "key 'axes.setup.ivt.battery.current_errors.noise_std'" in msg and "num" in msg
    p.write_text('campaign = "quick"\n[axes]\nsetup.telemetry.k_tl = [1]\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=r"key 'axes.setup.telemetry.k_tl'.*allowed keys here: .*k_tel"):
        load_sweep(p)
    p.write_text('campaign = "quick"\n[axes]\nsetup.telemetry.k_tel = {start = 250, stop = 1000, step = 250}\n',
                 encoding="utf-8")
    cfg, *_ = load_sweep(p)
    assert cfg.axis_values() == {"setup.telemetry.k_tel": [250.0, 500.0, 750.0, 1000.0]}


def test_an_interrupted_sweep_keeps_what_finished(tmp_path: Path, cache: Path, serial_table: pd.DataFrame,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    # Ctrl-C during the third run (in this process): the two finished rows stay in runs.csv and runs.parquet,
    # the interrupt reaches the caller, and --resume runs only the other two
    import benchtwin.studies.sweep as sweep_module

    real, finished = sweep_module.run_task, []

    def interrupted_on_the_third(task):  # type: ignore[no-untyped-def]
        if len(finished) == 2:
            raise KeyboardInterrupt
        finished.append(task.key)
        return real(task)

    monkeypatch.setattr(sweep_module, "run_task", interrupted_on_the_third)
    path = _file(tmp_path)
    with pytest.raises(KeyboardInterrupt):
        Sweep.from_file(path, cache_dir=cache).run(tmp_path / "out", workers=0, figures=False)
    monkeypatch.undo()
    assert sorted(read_table(tmp_path / "out")["run_key"]) == sorted(finished)
    assert sorted(pd.read_parquet(tmp_path / "out" / "runs.parquet")["run_key"]) == sorted(finished)
    again = Sweep.from_file(path, cache_dir=cache).run(tmp_path / "out", workers=0, resume=True, figures=False)
    assert (again.done, again.skipped) == (2, 2)
    pd.testing.assert_frame_equal(_comparable(read_table(tmp_path / "out")), _comparable(serial_table))
