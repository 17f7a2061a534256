"""The robosuite grippers a robot scene may mount on the Panda's flange, and how each opens and closes.

A gripper is one of robosuite's gripper files, attached (as robosuite's ``ManipulatorModel.add_gripper`` does)
by its first body to the arm's ``right_hand`` body with the pose the file gives it. Its opening is set the way
robosuite drives it: a closing command ``c`` in [-1 (open), 1 (closed)] is turned into one signed command per
actuator (the gripper class's ``format_action``), then into each actuator's control
``mid + half * sign * c`` of its ``ctrlrange`` (robosuite's ``Robot.grip_action``); physics then moves the fingers
(their tendons and equality constraints couple the joints of the Robotiq hands).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Gripper:
    """One robosuite gripper.

    Attributes:
        name: the name scene.json records (``gripper``).
        file: its MJCF file under robosuite's ``models/assets``.
        close_signs: per actuator (in the file's order), the sign robosuite's ``format_action`` gives a closing
            command.
    """

    name: str
    file: str
    close_signs: tuple[float, ...]

    def controls(self, ctrlrange, opening: float) -> list[float]:
        """Actuator controls for ``opening`` in [0 (closed), 1 (open)]; ``ctrlrange`` (A, 2) the actuators'."""
        c = 1.0 - 2.0 * float(opening)
        out = []
        for (lo, hi), sign in zip(ctrlrange, self.close_signs, strict=True):
            out.append(0.5 * (lo + hi) + 0.5 * (hi - lo) * sign * c)
        return out


GRIPPERS: dict[str, Gripper] = {
    g.name: g
    for g in (
        Gripper("panda", "grippers/panda_gripper.xml", (-1.0, 1.0)),
        Gripper("rethink", "grippers/rethink_gripper.xml", (1.0, -1.0)),
        Gripper("robotiq85", "grippers/robotiq_gripper_85.xml", (1.0, 1.0)),
        Gripper("robotiq140", "grippers/robotiq_gripper_140.xml", (1.0, -1.0)),
    )
}
