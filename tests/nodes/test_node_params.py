"""Each node declares its parameters' ranges: a value out of range ends it with exit 2 and one
line naming the parameter, before it opens a socket."""
from __future__ import annotations

import pytest

from incipient_slip.graph.runtime import run_node
from incipient_slip.nodes.estimator import Estimator
from incipient_slip.nodes.grip_controller import GripController
from incipient_slip.nodes.rig_sim import RigSim
from incipient_slip.nodes.supervisor import Supervisor


@pytest.mark.parametrize("node, arg, says", [
    (GripController, "s_d:=2", "s_d:=2.0 is above its range [0.0, 1.0]"),
    (GripController, "k:=-1", "k:=-1.0 must be >= 0.0"),
    (GripController, "k:=.inf", "k:=.inf is not a finite number"),
    (GripController, "max_force_kpa:=99", "max_force_kpa:=99.0 is above its range"),
    (GripController, "method:=bogus", 'method:="bogus" is not one of'),
    (GripController, "estimate_timeout_s:=0", "estimate_timeout_s:=0.0 must be >="),
    (RigSim, "steps:=-5", "steps:=-5 must be >= 1"),
    (RigSim, "normal_force_kpa:=9", "normal_force_kpa:=9.0 is above its range"),
    (Supervisor, "max_steps:=-5", "max_steps:=-5 must be >= 1"),
    (Estimator, "method:=none", 'method:="none" is not one of'),
    # the empty choice was listed as nothing ("is not one of , pseudo, ..."); it says what it means
    (Estimator, "label:=psuedo", 'label:="psuedo" is not one of "", pseudo, measured-ratio, true-ratio (label: '),
])
def test_out_of_range_parameter_is_exit_2_with_one_line(graph, capsys, node, arg, says):
    assert run_node(node, [arg]) == 2
    err = capsys.readouterr().err
    assert says in err and len(err.strip().splitlines()) == 1, err


def test_min_force_above_max_force_is_refused(graph, capsys):
    assert run_node(GripController, ["min_force_kpa:=5", "max_force_kpa:=4"]) == 2
    assert "min_force_kpa:=5.0 is above max_force_kpa:=4.0" in capsys.readouterr().err


def test_a_model_directory_is_reported_as_a_directory(graph, tmp_path, capsys):
    assert run_node(Estimator, [f"model:={tmp_path}"]) == 2
    err = capsys.readouterr().err
    assert f"model file {tmp_path} is a directory" in err and "does not exist" not in err
