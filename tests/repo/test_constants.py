"""One source per constant: the simulator's timing parameters agree with the wire contract."""
from incipient_slip import messages
from incipient_slip.control import EXIT_CODES
from incipient_slip.errors import EXIT_FAILURE, EXIT_FAULT, EXIT_SUCCESS, EXIT_USAGE
from incipient_slip.models.features import METHODS
from incipient_slip.sim.scene import load_scene


def test_the_simulated_rig_runs_on_the_wire_contracts_period_and_rates():
    timing = load_scene("paper").params["timing"]
    assert timing["period_s"] * 1e9 == messages.PERIOD_NS
    assert (timing["pac_rate_hz"], timing["slow_rate_hz"], timing["mocap_rate_hz"]) == (
        messages.PAC_RATE_HZ, messages.SLOW_RATE_HZ, messages.MOCAP_RATE_HZ)
    assert messages.PAC_RATE_HZ * messages.PERIOD_NS // 10**9 % messages.PAC_SAMPLES_PER_FRAME == 0


def test_estimation_methods_are_the_wire_methods_but_none():
    assert METHODS == tuple(m for m in messages.METHODS if m != "none")


def test_supervisor_exit_codes_are_distinct_from_usage():
    assert EXIT_CODES == {"success": EXIT_SUCCESS, "failure": EXIT_FAILURE, "fault": EXIT_FAULT}
    assert EXIT_USAGE not in EXIT_CODES.values()
