"""Real launches: one process test per contract of how a launch starts, hands shake and ends."""
from __future__ import annotations

import os
import signal
import textwrap
from pathlib import Path

from incipient_slip.messages import BiotacPac

NODES = Path(__file__).parent / "nodes"
EXITER, TALKER, LISTENER, STUBBORN = (NODES / f"{n}.py" for n in ("exiter", "talker", "listener", "stubborn"))


def launch(graph, doc: str, *args):
    path = graph.dir.parent / f"{graph.dir.name}.yaml"     # outside the graph directory
    path.write_text(textwrap.dedent(doc))
    return graph.spawn(["python", "-m", "incipient_slip.graph.launch", str(path), *args])


def finish(proc, timeout=30):
    out, err = proc.communicate(timeout=timeout)
    return proc.returncode, out.decode(), err.decode()


def alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_required_node_exit_ends_launch_with_its_code(graph):
    code = 3
    proc = launch(graph, f"""
        launch:
          - node: {{exec: {EXITER}, name: bystander}}
          - node: {{exec: {EXITER}, name: supervisor, required: true,
                    param: [{{name: after_s, value: 0.3}}, {{name: code, value: {code}}}]}}
    """)
    rc, _, err = finish(proc)
    assert rc == code
    assert "required node supervisor" in err and f"exit code {code}" in err
    assert os.listdir(graph.dir) == []


def test_a_node_that_needs_seconds_to_flush_at_shutdown_is_given_them_not_killed(graph):
    """At run end a loaded machine made rig_sim take over 5 s to stop and the launcher SIGKILLed
    it; a node gets the default grace (30 s) to flush."""
    proc = launch(graph, f"""
        launch:
          - node: {{exec: {EXITER}, name: slow_flusher, param: [{{name: flush_s, value: 7.0}}]}}
          - node: {{exec: {EXITER}, name: supervisor, required: true, param: [{{name: after_s, value: 0.3}}]}}
    """)
    rc, _, err = finish(proc, timeout=60)
    assert rc == 0 and "SIGKILL" not in err, err
    assert os.listdir(graph.dir) == []


def test_a_required_node_that_refuses_its_input_ends_the_launch_with_2_and_its_line_last(graph):
    """A bad model file: the estimator exits 2; the launch must not run on, nor bury the cause."""
    proc = launch(graph, f"""
        launch:
          - node: {{exec: {EXITER}, name: supervisor, required: true}}
          - node: {{exec: {EXITER}, name: estimator, required: true,
                    param: [{{name: after_s, value: 0.2}}, {{name: code, value: 2}}]}}
          - node: {{exec: {EXITER}, name: reader, respawn: true,
                    param: [{{name: after_s, value: 0.1}}, {{name: code, value: 2}}]}}
    """)
    rc, _, err = finish(proc)
    assert rc == 2
    assert err.rstrip().splitlines()[-1] == ("[launch] launch ends with code 2: required node estimator "
                                             "exit code 2: shutting down: time is up")
    assert "respawning reader" not in err     # exit 2 is not retried


def test_an_out_of_range_launch_arg_is_one_line_exit_2_and_starts_nothing(graph):
    proc = launch(graph, f"""
        launch:
          - arg: {{name: after_s, default: "1"}}
          - node: {{exec: {EXITER}, param: [{{name: after_s, value: "$(var after_s)"}}]}}
    """, "after_s:=-5")
    rc, out, err = finish(proc)
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and "after_s:=-5.0 must be >= 0.0" in err
    assert os.listdir(graph.dir) == []


def test_a_killed_required_node_ends_the_launch_and_leaves_no_files(graph, probe):
    proc = launch(graph, f"""
        launch:
          - node: {{exec: {EXITER}, name: estimator, required: true}}
          - node: {{exec: {EXITER}, name: other}}
    """)
    nodes = probe.nodes(["estimator", "other"], procs=[proc])
    os.kill(nodes["estimator"].pid, signal.SIGKILL)
    rc, _, err = finish(proc)
    assert rc == 128 + signal.SIGKILL
    assert "required node estimator died with signal SIGKILL" in err
    assert not alive(nodes["other"].pid)
    probe.close()
    assert os.listdir(graph.dir) == []    # the SIGKILLed node's announcement and socket too


def test_sigint_stops_every_node_and_exits_130(graph, probe):
    proc = launch(graph, f"""
        launch:
          - node: {{exec: {LISTENER}}}
          - node: {{exec: {TALKER}, param: [{{name: rate_hz, value: 200.0}}]}}
          - node: {{exec: {EXITER}}}
    """)
    nodes = probe.nodes(["listener", "talker", "exiter"], procs=[proc])
    probe.ready_on([BiotacPac], procs=[proc])       # the graph is live: frames are flowing
    proc.send_signal(signal.SIGINT)
    rc, _, err = finish(proc, timeout=10)
    assert rc == 128 + signal.SIGINT, err
    assert not any(alive(i.pid) for i in nodes.values())


def test_a_second_ctrl_c_kills_at_once_and_the_launch_says_so_with_3(graph, probe):
    proc = launch(graph, f"""
        launch:
          - node: {{exec: {STUBBORN}, name: stubborn}}
    """, "--grace", "60")
    node = probe.nodes(["stubborn"], procs=[proc])["stubborn"]
    proc.send_signal(signal.SIGINT)
    probe.until(lambda: "SIGINT: shutting down" in _peek(proc), 10, what="the first SIGINT seen")
    proc.send_signal(signal.SIGINT)
    rc, _, err = finish(proc, timeout=10)
    assert rc == 3 and "SIGKILL was needed for stubborn" in err
    assert not alive(node.pid)


def _peek(proc) -> str:
    """stderr read so far (non-blocking), kept on the process for finish()."""
    import fcntl
    fd = proc.stderr.fileno()
    fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) | os.O_NONBLOCK)
    try:
        chunk = proc.stderr.read() or b""
    except BlockingIOError:
        chunk = b""
    proc.seen = getattr(proc, "seen", b"") + chunk
    return proc.seen.decode(errors="replace")


def test_non_required_node_is_respawned(graph, probe):
    proc = launch(graph, f"""
        launch:
          - node: {{exec: {EXITER}, name: flaky, respawn: true, respawn_delay: 0.1,
                    param: [{{name: after_s, value: 0.2}}, {{name: code, value: 1}}]}}
    """)
    probe.until(lambda: _peek(proc).count("respawning flaky") >= 2, 60, what="two respawns")
    proc.send_signal(signal.SIGINT)
    rc, _, err = finish(proc)
    assert rc == 128 + signal.SIGINT, err
    assert "flaky exited with exit code 1; respawning in 0.1 s" in proc.seen.decode()


def test_a_publisher_waits_for_its_named_reader_not_for_a_recorder_started_before(graph, probe):
    """The lost-period-0 bug: `slip bag record` running before the launch satisfied a count of
    one subscriber per topic, so the source started before the slow reader listened."""
    recorder = []
    probe.node.create_raw_subscription(lambda topic, body, t: recorder.append(topic))
    proc = launch(graph, f"""
        launch:
          - node: {{exec: {TALKER}, param: [{{name: wait_readers, value: true}}, {{name: rate_hz, value: 500.0}}]}}
          - node: {{exec: {LISTENER}, required: true,
                    param: [{{name: start_delay_s, value: 1.0}}, {{name: count, value: 20}}]}}
    """)
    # (the stranger connects to the talker at its next directory check; on a loaded machine that
    # can come after this short run ended, so whether it heard anything is not asserted)
    probe.until(lambda: proc.poll() is not None, 120, what="the launch to end")
    rc, out, err = finish(proc)
    assert rc == 0, err
    assert "[listener] first seq 0" in out and "[listener] done 20 gaps 0" in out


def test_a_reader_that_refuses_its_input_ends_the_launch_its_publishers_wait_for_it(graph):
    """view:=foxglove with the viewer's port taken: the bridge (not required: if it dies mid-run
    the run goes on) exited at start, and every publisher waited for it as a named reader until
    its wait_timeout_s (300 s in stabilize.yaml). A node that exits 2 (bad input) while others
    wait for it ends the launch with 2 and its line."""
    proc = launch(graph, f"""
        launch:
          - node: {{exec: {TALKER}, required: true,
                    param: [{{name: wait_readers, value: true}}, {{name: count, value: 5}}]}}
          - node: {{exec: {LISTENER}, param: [{{name: refuse, value: true}}]}}
    """)
    rc, out, err = finish(proc, timeout=60)
    assert rc == 2, err
    assert "listener exited with exit code 2 (bad input) and talker waits for it" in err
    assert err.rstrip().splitlines()[-1] == ("[launch] launch ends with code 2: node listener exit code 2: "
                                             "Listener: node 'listener': refused its input (as a port taken "
                                             "since the check)")
    assert os.listdir(graph.dir) == []


def test_a_gate_that_fails_ends_the_launch_before_the_nodes_after_it_start(graph):
    proc = launch(graph, f"""
        launch:
          - node: {{exec: {EXITER}, name: check, gate: true,
                    param: [{{name: after_s, value: 1.0}}, {{name: code, value: 2}}]}}
          - node: {{exec: {EXITER}, name: device, required: true,
                    param: [{{name: after_s, value: 0.05}}, {{name: code, value: 5}}]}}
    """)
    rc, _, err = finish(proc)
    assert rc == 2, err
    assert "gate check exited with exit code 2; not started: device" in err
    assert "required node device" not in err and "[device]" not in err


def test_a_gate_that_passes_starts_the_nodes_after_it(graph):
    proc = launch(graph, f"""
        launch:
          - node: {{exec: {EXITER}, name: check, gate: true, param: [{{name: after_s, value: 0.2}}]}}
          - node: {{exec: {EXITER}, name: device, required: true,
                    param: [{{name: after_s, value: 0.2}}, {{name: code, value: 3}}]}}
    """)
    rc, _, err = finish(proc)
    assert rc == 3, err
    assert err.index("gate check passed; starting device") < err.index("required node device")


def test_a_required_node_interrupted_from_outside_ends_the_launch_non_zero(graph, probe):
    """SIGTERM or SIGINT to a node of a run (rig_sim, the estimator, the grip controller) ended
    the launch with 0, counted a success by scripts and CI: the node now stops cleanly and exits
    128 + the signal, and the launch with it."""
    for sig in (signal.SIGTERM, signal.SIGINT):
        proc = launch(graph, f"""
            launch:
              - node: {{exec: {EXITER}, name: bystander}}
              - node: {{exec: {EXITER}, name: rig, required: true}}
        """)
        node = probe.nodes(["rig", "bystander"], procs=[proc])["rig"]
        os.kill(node.pid, sig)
        rc, _, err = finish(proc)
        assert rc == 128 + sig, err
        assert f"required node rig exited with exit code {128 + sig} (stopped by {sig.name})" in err


def test_a_launch_whose_run_ended_well_but_needed_sigkill_to_stop_exits_3(graph, probe):
    """The docs said 1 for a stop that needed SIGKILL, the launcher returned the ending node's code
    (0 here, or 3): now 3, a fault (a node did not stop), unless the ending node's code is not 0."""
    proc = launch(graph, f"""
        launch:
          - node: {{exec: {STUBBORN}, name: stubborn}}
          - node: {{exec: {EXITER}, name: supervisor, required: true, param: [{{name: after_s, value: 1.0}}]}}
    """, "--grace", "1")
    rc, _, err = finish(proc)
    assert rc == 3 and "launch ends with code 3: SIGKILL was needed for stubborn" in err, err
