"""The event queue resource: systems talk by emitting events and reading them through cursors.

Every event gets a sequence number. A reader (made once, at plugin build time) remembers the last
sequence number it has seen, so each reader sees each event exactly once whichever stage it runs in,
and however many fixed simulation steps a frame holds (0..n). Old events are dropped after a few
frames; a reader that has not run for that long has missed them by design (like Bevy's events).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from typing import Any, Generic, TypeVar, overload

T = TypeVar("T")

#: frames an event stays readable after the frame it was emitted in
RETAIN_FRAMES = 8


class EventReader(Generic[T]):
    """A cursor over events of one type (or of every type when `kind` is None)."""

    def __init__(self, queue: EventQueue, kind: type[T] | None):
        self._queue = queue
        self._kind = kind
        self._seen = queue._next_seq - 1

    def read(self) -> list[T]:
        """Events of this reader's type emitted since the previous read, oldest first."""
        out: list[T] = []
        items = self._queue._items
        if not items or items[-1][0] <= self._seen:
            return out  # nothing new (most readers, most frames): no pass over the frames kept
        last = self._seen
        for seq, _frame, ev in items:
            if seq <= self._seen:
                continue
            last = seq
            if self._kind is None or isinstance(ev, self._kind):
                out.append(ev)
        self._seen = max(self._seen, last)
        return out

    def __iter__(self) -> Iterator[T]:
        return iter(self.read())


class EventQueue:
    """All events of one App; `emit` appends, readers consume independently."""

    def __init__(self) -> None:
        self._items: deque[tuple[int, int, Any]] = deque()
        self._next_seq = 1
        self._frame = 0
        self.log: list[Any] | None = None  # when a list, every emitted event is appended (tests, recording)

    def emit(self, event: Any) -> None:
        self._items.append((self._next_seq, self._frame, event))
        self._next_seq += 1
        if self.log is not None:
            self.log.append(event)

    # typed by the event class it reads: `for ev in reader.read()` then knows each event's fields
    @overload
    def reader(self, kind: type[T]) -> EventReader[T]: ...
    @overload
    def reader(self, kind: None = None) -> EventReader[Any]: ...
    def reader(self, kind: type[Any] | None = None) -> EventReader[Any]:
        """A new cursor that sees events of type `kind` (every event when None) emitted from now on."""
        return EventReader(self, kind)

    def begin_frame(self, frame: int) -> None:
        self._frame = frame
        while self._items and self._items[0][1] < frame - RETAIN_FRAMES:
            self._items.popleft()
