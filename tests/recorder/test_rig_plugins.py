from __future__ import annotations

import os
import pickle
import signal
import sys
import threading
from typing import TYPE_CHECKING

import pytest
import rig_plugins
from rig_plugins import TracingRig, install_entry_points, traces

from recorder import (
    FrozenTable,
    Moving,
    RecorderError,
    RigConfig,
    RigError,
    find_rig,
    is_exclusive,
    load_actions,
    load_objects,
    load_rig_config,
    register_rig,
    rig_factory,
    rig_names,
)
from recorder import _rigconfig as rigconfig
from recorder._cli import build_parser, main
from recorder.runner._record import record_action
from schemas import cli

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

    from recorder import ActionSpec, ObjectSpec, StreamItem

ACTIONS = ["--objects", "wood,foam_block", "--actions", "P1", "--trials", "2"]


@pytest.fixture(autouse=True)
def entry_points(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    install_entry_points(tmp_path / "site", monkeypatch)


@pytest.fixture
def log_dir(tmp_path: Path) -> Path:
    (tmp_path / "log").mkdir()
    return tmp_path / "log"


def _dataset(out: Path, rig: str, log_dir: Path, *extra: str) -> list[str]:
    options = ["--rig", rig, "--rig-option", f"log_dir={log_dir}"]
    return ["dataset", "--out", str(out), *ACTIONS, *options, *extra]


def test_installed_plugins_are_listed_after_the_projects_own() -> None:
    names = rig_names()
    assert names[:2] == ("sim", "ur")
    assert {"fake", "fake-exclusive", "fake-bare", "broken"} <= set(names)
    assert find_rig("fake") is rig_plugins.PLUGIN
    assert find_rig("fake-exclusive").exclusive


def test_an_installed_plugin_records_in_spawned_workers_and_in_action(
    tmp_path: Path, log_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(_dataset(tmp_path / "d", "fake", log_dir, "--workers", "2")) == 0
    pids = {pid for pid, _ in traces(log_dir)}
    assert len(traces(log_dir)) == 4
    assert os.getpid() not in pids  # the workers recorded
    assert len(list((tmp_path / "d").rglob("*.mcap"))) == 4
    assert (tmp_path / "d" / "index.parquet").is_file()
    capsys.readouterr()
    argv = ["action", "--object", "wood", "--action", "S1", "--out", str(tmp_path / "a")]
    assert main([*argv, "--rig", "fake", "--rig-option", f"log_dir={log_dir}"]) == 0
    assert (os.getpid(), "perform-wood-S1-1") in traces(log_dir)
    assert (tmp_path / "a" / "wood" / "S1" / "001.mcap").is_file()


def test_an_exclusive_rig_records_in_the_main_process_whatever_workers_say(
    tmp_path: Path, log_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = _dataset(tmp_path / "d", "fake-exclusive", log_dir, "--workers", "2")
    assert main(argv) == 0
    assert [pid for pid, _ in traces(log_dir)] == [os.getpid()] * 4
    err = capsys.readouterr().err.splitlines()
    notes = [line for line in err if "exclusive" in line]
    expected = (
        "atikt-record: rig fake-exclusive is exclusive hardware: one action at a time in this "
        "process (--workers 2 not used)"
    )
    assert notes == [expected]


def test_a_rig_registered_at_run_time_records_in_workers(
    tmp_path: Path, log_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(rigconfig, "_BUILDERS", {})
    register_rig("lab", rig_plugins.bare_builder)
    assert "lab" in rig_names()
    assert main(_dataset(tmp_path / "d", "lab", log_dir, "--workers", "2")) == 0
    assert len(traces(log_dir)) == 4
    assert os.getpid() not in {pid for pid, _ in traces(log_dir)}


def test_a_builder_that_cannot_reach_the_workers_is_one_line_before_they_start(
    tmp_path: Path,
    log_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    lock = threading.Lock()

    def locked(seed: int, options: object) -> rig_plugins.TracingRig:
        with lock:
            return rig_plugins.bare_builder(seed, options)  # type: ignore[arg-type]

    monkeypatch.setattr(rigconfig, "_BUILDERS", {})
    register_rig("locked", locked)
    assert main(_dataset(tmp_path / "d", "locked", log_dir, "--workers", "2")) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1
    assert "rig locked: its builder cannot be sent to worker processes" in err[0]
    assert "--workers 1" in err[0]
    assert traces(log_dir) == []
    assert main(_dataset(tmp_path / "d", "locked", log_dir, "--workers", "1")) == 0


def test_a_bare_builder_entry_point_is_wrapped_and_reads_no_tables(tmp_path: Path) -> None:
    config = tmp_path / "rig.toml"
    config.write_text(f'rig = "fake-bare"\n[options]\nlog_dir = "{tmp_path}"\n')
    factory = rig_factory(load_rig_config(config))
    assert not is_exclusive(factory)
    assert isinstance(factory(3), rig_plugins.TracingRig)
    config.write_text(config.read_text() + "[limits]\nspeed_m_s = 0.1\n")
    with pytest.raises(RecorderError, match=r"unknown tables \[limits\]; rig 'fake-bare'"):
        rig_factory(load_rig_config(config))(3)


@pytest.mark.parametrize(
    ("rig", "expected"),
    [
        (
            "broken",
            (
                "rig 'broken' could not be loaded (ModuleNotFoundError: No module named "
                "'no_such_module_for_atikt_tests'; entry point broken = "
                "'no_such_module_for_atikt_tests:PLUGIN' of atikt-test-rigs in group "
                "atikt.rigs); reinstall or fix the package that provides it, or choose "
                "another --rig"
            ),
        ),
        ("not-a-plugin", "rig 'not-a-plugin' could not be loaded (entry point not-a-plugin"),
        ("ur", "rig 'ur' could not be loaded (ModuleNotFoundError: "),
    ],
)
def test_a_plugin_that_does_not_load_is_one_line(
    tmp_path: Path,
    rig: str,
    expected: str,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # the commands are imported first (serve-sim's virtual lab speaks the UR's protocol, so
    # it imports recorder.ur): what is checked is the rig's loading, not the commands'
    build_parser()
    monkeypatch.setitem(sys.modules, "recorder.ur", None)  # as on a branch without it
    out = tmp_path / "out"
    argv = ["action", "--object", "wood", "--action", "P1", "--out", str(out), "--rig", rig]
    assert main(argv) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1
    assert expected in err[0]
    assert not out.exists()


def test_a_rig_configuration_keeps_its_tables_frozen_and_pickles(tmp_path: Path) -> None:
    path = tmp_path / "lab.toml"
    path.write_text(
        'rig = "fake"\n[options]\nhost = "10.0.0.2"\n[limits]\nspeed_m_s = 0.1\n'
        "[objects.wood]\npose = [0.1, 0.2, 0.3]\n"
    )
    config = load_rig_config(path, options=["port=30004"])
    assert dict(config.options) == {"host": "10.0.0.2", "port": 30004}
    assert config.sections["objects"]["wood"]["pose"] == (0.1, 0.2, 0.3)
    assert isinstance(config.sections["objects"], FrozenTable)
    assert config.source == str(path)
    with pytest.raises(TypeError):
        config.sections["limits"]["speed_m_s"] = 1.0
    assert pickle.loads(pickle.dumps(config)) == config  # noqa: S301
    assert RigConfig("fake", {"a": 1}) == RigConfig("fake", FrozenTable({"a": 1}))


def test_top_level_values_other_than_rig_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "lab.toml"
    path.write_text('rig = "sim"\nhost = "x"\nport = 1\n[limits]\n')
    with pytest.raises(RecorderError, match=r"unknown keys \['host', 'port'\]"):
        load_rig_config(path)


def test_register_rig_refuses_a_name_found_first_and_a_non_builder() -> None:
    with pytest.raises(RecorderError, match=r"'sim'.*taken"):
        register_rig("sim", rig_plugins.bare_builder)
    with pytest.raises(RecorderError, match=r"'fake'.*taken"):
        register_rig("fake", rig_plugins.bare_builder)
    with pytest.raises(RecorderError, match=r"give a recorder\.RigPlugin"):
        register_rig("lab", 3)  # type: ignore[arg-type]


class _MovingRig(TracingRig):
    """A lab's rig that moves an arm by itself (``recorder.Moving``): it can refuse."""

    refuse = ""
    stopped = False

    def check_ready(self) -> None:
        if self.refuse:
            raise RigError(self.refuse)

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        try:
            for count, item in enumerate(super().perform(obj, action, trial)):
                if count == 50:
                    os.kill(os.getpid(), signal.SIGTSTP)
                yield item
        finally:
            self.stopped = True  # its own stop, whatever ended the action


@pytest.mark.usefixtures("suspend_caught")
def test_a_rig_that_moves_an_arm_by_itself_is_recorded_as_the_runners_arms_are(
    tmp_path: Path,
) -> None:
    # the typed capability, not the runner's class: a refusal before anything moves, and
    # Ctrl-Z ends the run (never a suspended recorder with the arm unwatched), data kept
    obj, action = load_objects()["wood"], load_actions()["P1"]
    rig = _MovingRig(0, tmp_path)
    assert isinstance(rig, Moving)
    rig.refuse = "lab.toml: the arm is not homed; home it, then retry"
    with rig, pytest.raises(RigError, match="not homed"):
        record_action(rig, obj, action, 1, tmp_path / "out" / "001.mcap", seed=0)
    assert not list(tmp_path.glob("*perform*"))  # it never began
    rig.refuse = ""
    with rig, pytest.raises(cli.Suspended):
        record_action(rig, obj, action, 1, tmp_path / "out" / "001.mcap", seed=0)
    assert rig.stopped
    assert (tmp_path / "out" / "001.incomplete.mcap").exists()
