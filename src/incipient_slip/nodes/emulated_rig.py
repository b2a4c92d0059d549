"""emulated_rig: the physical world of the rig, emulated: every device around one simulated contact.

    python -m incipient_slip.nodes.emulated_rig dir:=/tmp/emu robot_address:=127.0.0.3

Runs `devices.emulated_rig.EmulatedRig` (the BioTac bridge and the Zaber stage on ptys under
`dir`, a NatNet server on 127.0.0.1, a UR controller on `robot_address`, the PZT's WAV sink
`<dir>/pzt.wav`), all sharing one `sim.Rig` stepped in real time. The real device nodes talk
to it (`launch stabilize.yaml rig:=emulated`); it publishes nothing of the rig's on the graph.

It runs at a raised priority (`nice`, default -10, every thread of it):
the devices it stands in for are never starved of the CPU, so a CPU hog beside the graph slows
the host's nodes, as on the lab's rig, but not the devices' clocks and replies. Raising the
priority needs CAP_SYS_NICE or an RLIMIT_NICE (`ulimit -e`); without it the node says so once
and runs at the normal priority.

The pull starts once the BioTac is tared (`linear_actuator wait_tare:=true`, as on the real
rig). It logs the contact's truth every `log_every` periods.
Address or port taken, or a bad scene: exit 2 with one line.
"""
from __future__ import annotations

import os
import tempfile

from incipient_slip import control
from incipient_slip.errors import EXIT_FAULT
from incipient_slip.extras import needed
from incipient_slip.graph.params import Param, ParamError, checked_value
from incipient_slip.graph.runtime import Node, run_node

try:
    from incipient_slip.devices.emulated_rig import EmulatedRig
    from incipient_slip.sim.scene import SceneError, load_scene
except ModuleNotFoundError as exc:      # a lab PC's lean install: name the [sim] extra
    raise needed(exc) from None


class EmulatedRigNode(Node):
    """Serves the emulated devices and steps the shared contact in real time."""

    PARAMS = {
        "dir": Param("", help="directory of the pty links biotac, zaber and the PZT sink pzt.wav "
                              "('' = a new temp dir)"),
        "scene": Param("", help='simulator scene; "": the scene of the method (control.SCENE_OF_METHOD)'),
        "method": Param("injection", help='the closed loop\'s method, whose scene scene:="" runs'),
        "material": Param("", help="object material ('' = the scene's first)"),
        "seed": Param(0, lo=0, help="seed of the simulated contact"),
        "robot_address": Param("127.0.0.3", help="loopback address of the fake UR controller"),
        "natnet_command_port": Param(41510, lo=1, hi=65535, help="NatNet command port on 127.0.0.1"),
        "natnet_data_port": Param(41511, lo=1, hi=65535, help="NatNet data port on 127.0.0.1"),
        "start_mm": Param(0.0, lo=-1000.0, hi=1000.0, help="stage position at zero pull (linear_actuator start_mm)"),
        "rated_rms": Param(0.25, lo=1e-6, hi=1.0, help="the PZT's 0 dB RMS (pzt_injector rated_rms)"),
        "newton_per_kpa": Param(0.0, lo=0.0, hi=10.0, help="hidden calibration: the finger's N per kPa of P_DC (0: the scene's)"),
        "spring_n_per_mm": Param(0.0, lo=0.0, hi=10.0, help="hidden calibration: the rail spring's N/mm (0: the scene's)"),
        "tick_s": Param(0.004, lo=0.001, hi=0.05, help="how often the contact and the NatNet pose advance, s"),
        "log_every": Param(10, lo=0, help="log the contact's truth every this many periods (0: never)"),
        "nice": Param(-10, lo=-20, hi=19, help="scheduling priority of the emulators (hardware is never starved)"),
    }
    INPUTS: dict = {}

    @classmethod
    def check_inputs(cls, params: dict, name: str = "emulated_rig"):
        """The scene and the material in it, before a launch starts any node (ParamError)."""
        try:
            scene = load_scene(control.scene_of(params["scene"], params["method"]))
        except (SceneError, ValueError) as exc:
            raise ParamError(f"node {name!r}: parameter 'scene': {exc}") from None
        checked_value(name, "material", params["material"], scene.material)

    def __init__(self, **kwargs):
        super().__init__("emulated_rig", **kwargs)
        p = self.param
        directory = p("dir") or tempfile.mkdtemp(prefix="slip-emulated-")
        refused = set_priority(p("nice"))       # before the emulators' threads and processes start
        if refused:
            self.warn(f"runs at the normal priority, not nice {p('nice')} ({refused}): under CPU load "
                      f"the emulated devices can be starved, which the hardware never is; give the "
                      f"user an RLIMIT_NICE (ulimit -e) or run with CAP_SYS_NICE")
        try:
            scene = control.scene_of(p("scene"), p("method"))
            self.rig = EmulatedRig(directory, scene=scene, material=p("material"), seed=p("seed"),
                                   robot_address=p("robot_address"),
                                   natnet_command_port=p("natnet_command_port"),
                                   natnet_data_port=p("natnet_data_port"), start_mm=p("start_mm"),
                                   rated_rms=p("rated_rms"), newton_per_kpa=p("newton_per_kpa") or None,
                                   spring_n_per_mm=p("spring_n_per_mm") or None)
            self.rig.start()
        except (SceneError, ValueError, OSError) as exc:
            raise ParamError(f"node {self.name!r}: cannot start the emulated rig: {exc}") from None
        self.on_shutdown(self.rig.stop)
        self.log(f"BioTac bridge {self.rig.biotac_link}, Zaber {self.rig.zaber_link}, NatNet "
                 f"127.0.0.1:{p('natnet_command_port')}, UR {p('robot_address')}, PZT sink "
                 f"{self.rig.pzt_path}; scene {scene}, material {self.rig.shared.rig.material}, "
                 f"seed {p('seed')}, real time, nice {os.getpriority(os.PRIO_PROCESS, 0)}")
        self.logged = 0
        self.create_timer(p("tick_s"), self.tick)

    def tick(self) -> None:
        try:
            self.rig.tick()
        except (ValueError, ArithmeticError) as exc:      # SimulationError is a ValueError
            self.warn(f"the simulated contact failed: {exc}")
            return self.shutdown("simulator error", EXIT_FAULT)
        if self.rig.error() is not None:
            self.warn(f"the BioTac emulator stopped: {self.rig.error()}")
            return self.shutdown("BioTac emulator error", EXIT_FAULT)
        every = self.param("log_every")
        truth = self.rig.shared.truth
        while every and self.logged < len(truth):
            t = truth[self.logged]
            self.logged += 1
            if t.period % every == 0:
                self.log(f"period {t.period}: F_N {t.normal_force_kpa:.2f} kPa (press {t.depth_mm:.2f} mm), "
                         f"actuator {t.actuator_mm:.3f} mm, y {t.object_y_mm:.3f} mm, "
                         f"stick ratio {t.stick_area_ratio:.2f}, PZT {'on' if t.pzt_on else 'off'}; "
                         f"reference instruments: scale {self.rig.instruments()['scale_n']:.3f} N, spring "
                         f"gauge {self.rig.instruments()['spring_gauge_n']:.4f} N")


def set_priority(nice: int) -> str:
    """Sets the nice value of every thread of this process (on Linux it is per thread; threads
    and processes started later inherit it); returns "" or, when the system refuses, why."""
    try:
        threads = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:               # no /proc: this thread, and what it starts
        threads = [0]
    try:
        for tid in threads:
            os.setpriority(os.PRIO_PROCESS, tid, nice)
    except OSError as exc:        # EACCES/EPERM: no CAP_SYS_NICE, RLIMIT_NICE too low
        return exc.strerror or str(exc)
    return ""


def main(argv=None):
    return run_node(EmulatedRigNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
