"""`slip topic ...` and `slip bag ...`: what they print, and one clear line + exit 2 on bad input.

The commands are run as `python -m incipient_slip.graph.tools` (the same handlers `slip`
registers) so that these tests do not depend on the other areas' sub-commands.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from incipient_slip.graph import tools
from incipient_slip.graph.bag import bag_info

DEMO = Path(__file__).resolve().parents[1] / "data" / "demo.mcap"
TOOLS = [sys.executable, "-m", "incipient_slip.graph.tools"]


def slip(*args, timeout=30, env=None) -> subprocess.CompletedProcess:
    return subprocess.run(TOOLS + [str(a) for a in args], capture_output=True, text=True,
                          timeout=timeout, env=env)


@pytest.mark.timeout(30)
def test_bag_info_prints_topics_types_counts_and_rates():
    run = slip("bag", "info", DEMO)
    assert run.returncode == 0, run.stderr
    assert "messages:  648" in run.stdout
    pac = next(line for line in run.stdout.splitlines() if "/biotac/pac" in line).split()
    assert pac[:3] == ["/biotac/pac", "BiotacPac", "200"] and float(pac[3]) == pytest.approx(100, rel=0.02)


@pytest.mark.timeout(30)
def test_bag_info_json_matches_the_library(capsys):
    assert tools.main(["bag", "info", str(DEMO), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == json.loads(json.dumps(bag_info(DEMO).to_plain()))


def _truncated(tmp_path: Path) -> Path:
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(DEMO.read_bytes()[:20_000])
    return cut


@pytest.mark.timeout(20)
@pytest.mark.parametrize("args, says", [
    (["bag", "info", "{tmp}/missing.mcap"], "missing.mcap: no such file"),
    (["bag", "recover", "{tmp}/missing.mcap", "{tmp}/out.mcap"], "missing.mcap: no such file"),
    (["bag", "recover", __file__, "{tmp}/out.mcap"], "test_bag_tools.py: not an MCAP file"),
    (["bag", "recover", "{cut}", "{cut}"], "is the input file"),
    (["bag", "recover", "{cut}", str(DEMO)], "exists; pass --force"),
    (["bag", "recover", "{cut}", "{tmp}/no/dir/out.mcap"], "does not exist"),
    (["bag", "export", "{cut}", "{tmp}/out.mcap", "--foxglove"], "cut.mcap: truncated MCAP file"),
    (["bag", "export", str(DEMO), "{tmp}/out.mcap"], "required: --foxglove"),
    (["bag", "export", "{tmp}/missing.mcap", "{tmp}/out.mcap", "--foxglove"], "no such file"),
    (["bag", "info", __file__], "test_bag_tools.py: not an MCAP file"),
    (["bag", "play", "{cut}"], "cut.mcap: truncated MCAP file"),
    (["bag", "play", str(DEMO), "--rate", "0"], "--rate must be > 0"),
    (["bag", "play", str(DEMO), "--topics", "/nope"], "no topic /nope"),
    (["bag", "play", str(DEMO), "--rate", "2", "--max-speed"], "not allowed with argument"),
    (["bag", "record", "{tmp}/no/such/dir/out.mcap"], "does not exist"),
    (["bag", "record", "{tmp}/out.mcap", "biotac/pac"], "must start with '/'"),
    (["topic", "echo", "slip/estimate"], "must start with '/'"),
    (["topic", "hz", "/biotac/pac", "--window", "0"], "--window must be > 0"),
], ids=lambda v: v if isinstance(v, str) else " ".join(v[:2]))
def test_bad_input_is_one_clear_line_and_exit_code_2(tmp_path, capsys, args, says):
    cut = _truncated(tmp_path)
    try:    # in-process: the same handlers as the command, without a process start per case
        code = tools.main([a.format(tmp=tmp_path, cut=cut) for a in args])
    except SystemExit as exc:   # argparse's own usage errors
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2, err
    assert says in err


@pytest.mark.timeout(30)
def test_bag_info_on_an_unfinished_file_says_so_and_what_is_recoverable(tmp_path, capsys):
    cut = _truncated(tmp_path)
    assert tools.main(["bag", "info", str(cut)]) == 0
    out = capsys.readouterr().out
    assert "status:    UNFINISHED" in out and "bytes at the end unreadable" in out
    assert "0 messages (below) are recoverable" in out     # the demo is one chunk: all of it cut
    assert tools.main(["bag", "info", str(cut), "--json"]) == 0
    plain = json.loads(capsys.readouterr().out)
    assert plain["damage"]["finished"] is False and plain["message_count"] == 0


@pytest.mark.timeout(30)
def test_bag_recover_and_export_print_what_they_did(tmp_path, capsys):
    assert tools.main(["bag", "recover", str(DEMO), str(tmp_path / "r.mcap")]) == 0
    out = capsys.readouterr().out
    assert "recovered 648 messages on 5 topics" in out and "finished, nothing lost" in out
    assert "recovered per topic:\n  /actuator/state: " in out
    assert tools.main(["bag", "export", str(DEMO), str(tmp_path / "f.mcap"), "--foxglove"]) == 0
    out = capsys.readouterr().out
    assert "exported 848 messages on 6 JSON channels" in out     # 648 + 200 P_AC as audio
    assert "/biotac/pac/audio: 200" in out


@pytest.fixture
def playing(graph):
    """A looping replay of the demo recording in a private graph."""
    proc = graph.spawn(TOOLS + ["bag", "play", str(DEMO), "--loop", "--wait-subscribers", "0"])
    yield graph
    proc.terminate()
    proc.wait(timeout=10)


@pytest.mark.timeout(60)
def test_topic_echo_prints_count_messages_as_json_lines(playing):
    run = slip("topic", "echo", "/actuator/state", "--count", "2", "--json", env=playing.env)
    assert run.returncode == 0, run.stderr
    lines = [json.loads(line) for line in run.stdout.splitlines()]
    assert len(lines) == 2
    assert {(m["topic"], m["type"]) for m in lines} == {("/actuator/state", "ActuatorState")}


@pytest.mark.timeout(60)
def test_topic_echo_prints_yaml_documents(playing):
    run = slip("topic", "echo", "/pzt/state", "-n", "1", env=playing.env)
    assert run.returncode == 0, run.stderr
    import yaml
    (doc,) = list(yaml.safe_load_all(run.stdout))
    assert doc["type"] == "PztState" and doc["enabled"] is True


@pytest.mark.timeout(60)
def test_topic_list_shows_published_topics_types_and_rates(playing):
    # the player announces its topics when it starts: wait for that, not for a fixed time
    rows = []
    for _ in range(20):
        run = slip("topic", "list", "--json", "--duration", "1.5", env=playing.env)
        assert run.returncode == 0, run.stderr
        rows = {r["topic"]: r for r in json.loads(run.stdout)}
        if "/biotac/pac" in rows and rows["/biotac/pac"]["rate_hz"] > 0:
            break
    assert rows["/biotac/pac"]["type"] == "BiotacPac"
    assert rows["/biotac/pac"]["publishers"] == ["replay"]
    assert 50 < rows["/biotac/pac"]["rate_hz"] < 150
    assert rows["/object/pose"]["type"] == "ObjectPose"


@pytest.mark.timeout(60)
def test_topic_hz_reports_the_rate(playing):
    run = slip("topic", "hz", "/biotac/pac", "--duration", "3.5", env=playing.env)
    assert run.returncode == 0, run.stderr
    rates = [float(line.split("by stamps ")[1].split()[0]) for line in run.stdout.splitlines()
             if "by stamps" in line]
    assert rates and rates[-1] == pytest.approx(100.0, rel=0.01)


@pytest.mark.timeout(60)
def test_demo_launch_prints_a_summary_and_exits_0(graph):
    run = subprocess.run([sys.executable, "-m", "incipient_slip.graph.launch", "demo.yaml",
                          "rate:=4"], capture_output=True, text=True, timeout=50, env=graph.env)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "648 messages on 5 topics" in run.stdout
    assert "PASS" in run.stdout


@pytest.mark.timeout(60)
def test_topic_echo_into_a_reader_that_leaves_ends_cleanly_and_withdraws_itself(playing):
    """`slip topic echo ... | head`: the echo once died by SIGPIPE and left its announcement,
    which the next tool removed with a warning."""
    from incipient_slip.graph import discovery
    proc = subprocess.Popen(TOOLS + ["topic", "echo", "/biotac/pac", "--json"], env=playing.env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    first = proc.stdout.readline()                # what `head -1` reads, then it goes away
    proc.stdout.close()
    assert proc.wait(timeout=30) == 0
    assert json.loads(first)["topic"] == "/biotac/pac"
    err = proc.stderr.read().decode()
    assert "Traceback" not in err and "BrokenPipe" not in err, err
    assert "slip_topic_echo" not in [n.name for n in discovery.scan(playing.dir, clean=False)]
    assert not [p for p in playing.dir.iterdir() if p.name.startswith("slip_topic_echo")]


@pytest.mark.timeout(30)
def test_a_printing_command_into_a_reader_that_leaves_ends_without_a_traceback():
    # stdout block-buffered, as in a user's shell (the flush at exit once raised outside the handler)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    proc = subprocess.Popen(TOOLS + ["bag", "info", DEMO], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    proc.stdout.close()                           # gone before the first line
    assert proc.wait(timeout=30) == 141
    assert proc.stderr.read() == b""
