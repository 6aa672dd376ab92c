"""`python -m env_server.tools.ray`'s command line, its sweep shards' argv and its address
file, without Ray: the parts of the launcher test_ray.py does not need a cluster for.
"""

from __future__ import annotations

import os

import pytest
from conftest import read_addresses

from env_server.tools.ray import sweep
from env_server.tools.ray.fleet import write_address_file
from env_server.tools.ray.options import parse


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--num-servers", "0"], "--num-servers: expected >= 1, got 0"),
        (["--num-servers", "1", "--startup-timeout", "0"], "--startup-timeout: expected finite seconds > 0, got 0"),
        (
            ["--num-servers", "1", "--ray-start-timeout", "inf"],
            "--ray-start-timeout: expected finite seconds > 0, got inf",
        ),
        (
            ["--num-servers", "1", "--ray-start-timeout", "nan"],
            "--ray-start-timeout: expected finite seconds > 0, got nan",
        ),
        (["--num-servers", "2", "--server-args", "--port 5000"], "other than --host, --port and --list"),
        (["--num-servers", "2", "--server-args", "'unclosed"], "--server-args: expected a shell-quoted string"),
        (["--num-servers", "2", "--"], "expected a COMMAND after '--'"),
        (
            ["--num-servers", "1", "--sweep-shards", "2", "--", "agent", "sweep", "--config", "s.toml"],
            "--sweep-dir DIR",
        ),
        (
            ["--num-servers", "1", "--sweep-dir", "d", "--", "agent", "sweep"],
            "--sweep-dir: expected with --sweep-shards",
        ),
        (["--num-servers", "1", "--sweep-shards", "0", "--sweep-dir", "d"], "--sweep-shards: expected >= 1, got 0"),
        (
            ["--num-servers", "1", "--sweep-shards", "2", "--sweep-dir", "d", "--", "agent", "train"],
            "agent sweep --config",
        ),
        (
            [
                "--num-servers",
                "1",
                "--sweep-shards",
                "2",
                "--sweep-dir",
                "d",
                "--",
                "agent",
                "sweep",
                "--config=s",
                "--dir",
                "x",
            ],
            "expected no --dir in COMMAND",
        ),
    ],
)
def test_bad_flags_are_refused_naming_the_flag(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        parse(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_command_is_everything_after_the_first_separator():
    opts = parse(["--num-servers", "2", "--server-args", "--max-sessions 8", "--", "agent", "train", "--", "x"])
    assert opts.server_args == ["--max-sessions", "8"]
    assert opts.command == ["agent", "train", "--", "x"]
    assert parse(["--num-servers", "1"]).command == []


def test_a_shard_starts_with_its_slice_and_resumes_with_the_folder_alone():
    command = ["agent", "sweep", "--config", "s.toml", "--set", "seed=1", "--total-env-steps=9", "--device", "cpu"]
    assert sweep.start_argv(command, 1, 3, "/d/shard-1-of-3") == [
        *command,
        "--shard",
        "1/3",
        "--dir",
        "/d/shard-1-of-3",
    ]
    # A resume reads the sweep from its folder: the flags that made it go, the rest stay.
    assert sweep.resume_argv(command, "/d/x") == ["agent", "sweep", "--resume", "/d/x", "--device", "cpu"]
    assert sweep.report_argv(command, ["/a", "/b"], "/d/front") == [
        "agent", "sweep", "--report", "/a", "/b", "--dir", "/d/front",
    ]  # fmt: skip
    assert sweep.absolute(["bin/agent", "sweep", "--config", "s.toml"])[::3] == [
        os.path.abspath("bin/agent"),
        os.path.abspath("s.toml"),
    ]


def test_the_address_file_is_replaced_whole(tmp_path):
    path = str(tmp_path / "servers.txt")
    write_address_file(path, ["127.0.0.1:1", "127.0.0.1:2"], 3)
    assert read_addresses(path) == ["127.0.0.1:1", "127.0.0.1:2"]
    assert open(path).readline() == "# env servers from python -m env_server.tools.ray: 2 of 3 up\n"
    write_address_file(path, [], 3)
    assert read_addresses(path) == []
    assert os.listdir(tmp_path) == ["servers.txt"]  # no temporary file left behind
