"""Closed-loop policies in the robot world: tasks in MuJoCo with robosuite's assets (``tasks``, ``world``), the
Panda driven to keyposes by its joints (``control``), a scripted expert on privileged state (``expert``), episodes
run decision by decision (``rollout``), and demonstrations recorded (``collect``) in a documented layout
(``episodes``). MuJoCo is imported only where a world is built (the ``sim`` extra)."""
