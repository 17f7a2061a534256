"""The edit history: operations in the order they were done, and a cursor between the done and the undone ones.
A drag is a :class:`Gesture`: its steps are done as the mouse moves, and it enters the history as one operation
when it ends."""

from __future__ import annotations

from dataclasses import dataclass

from particlesplat.editing.operations import Operation


@dataclass
class Gesture:
    """A drag under way: ``key`` (the tool's gesture id and what it changes) and the one ``operation`` its steps
    add up to, done already and committed to the history when the drag ends."""

    key: tuple
    operation: Operation


class History:
    """Operations 0..cursor-1 are done, cursor.. were undone (the next to redo first); adding one drops those.
    ``gesture``: the drag under way, whose operation follows the done ones once it ends."""

    def __init__(self) -> None:
        self._ops: list[Operation] = []
        self.cursor = 0
        self.gesture: Gesture | None = None

    @property
    def undo(self) -> list[Operation]:
        """The done operations, oldest first (the next to undo last); a drag under way is the last."""
        return self._ops[: self.cursor] + ([self.gesture.operation] if self.gesture is not None else [])

    def end_gesture(self) -> None:
        """The drag under way, if any, ends: its operation is added."""
        if self.gesture is not None:
            op, self.gesture = self.gesture.operation, None
            self.add(op)

    @property
    def redo(self) -> list[Operation]:
        """The undone operations, the next to redo last."""
        return self._ops[self.cursor :][::-1]

    def add(self, op: Operation) -> None:
        """``op`` was done: it follows the done ones, and what was undone can no longer be redone."""
        if self.gesture is not None:
            raise RuntimeError("History.add: end the gesture under way first")
        del self._ops[self.cursor :]
        self._ops.append(op)
        self.cursor += 1

    def back(self) -> Operation | None:
        """The operation to undo (the cursor moves before it), or None."""
        if self.cursor == 0:
            return None
        self.cursor -= 1
        return self._ops[self.cursor]

    def forward(self) -> Operation | None:
        """The operation to redo (the cursor moves past it), or None."""
        if self.cursor == len(self._ops):
            return None
        self.cursor += 1
        return self._ops[self.cursor - 1]

    def mark(self) -> tuple[int, list[Operation]]:
        """The history as it is, for :meth:`restore` after the operations added since were undone."""
        return self.cursor, list(self._ops)

    def restore(self, mark: tuple[int, list[Operation]]) -> None:
        cursor, ops = mark
        if self.cursor != cursor:
            raise RuntimeError("History.restore: undo the operations added since the mark first")
        self._ops = list(ops)
