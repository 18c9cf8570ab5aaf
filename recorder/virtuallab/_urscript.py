"""The URScript subset the virtual lab runs: programs parsed into calls, checked like a compiler.

A UR controller's secondary interface takes a program as text: ``def name(): ... end`` with
one statement per line, or a single line. The virtual lab runs the calls the UR rig sends
(``recorder.ur._script.FUNCTIONS``): ``textmsg``, ``sleep``, ``movel``, ``speedl``, ``stopl``,
``force_mode``, ``end_force_mode``, ``get_actual_tcp_pose``. A line is parsed with Python's
own parser (a URScript call with numbers, lists, strings, ``p[...]`` poses and keyword
arguments is a valid Python expression), so no hand-written tokenizer can disagree with it;
values are then read from the syntax tree, never evaluated.

A program the lab cannot run (an unknown function, a line that is not a call, an argument
that is not a literal) is refused whole, as a controller's compiler refuses it: one error line
per problem, and the program does not run.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from recorder.ur._script import FUNCTIONS

if TYPE_CHECKING:
    from collections.abc import Sequence

#: Largest program the lab accepts, bytes (a controller's memory is bounded too).
MAX_PROGRAM_BYTES = 1 << 20


@dataclass(frozen=True, slots=True)
class Pose:
    """A ``p[x, y, z, rx, ry, rz]`` literal."""

    values: tuple[float, ...]


@dataclass(frozen=True, slots=True)
class ActualPose:
    """The value of ``get_actual_tcp_pose()`` as an argument: read when the call runs."""


Value = float | str | bool | tuple[float, ...] | Pose | ActualPose


@dataclass(frozen=True, slots=True)
class Call:
    """One function call of a program.

    Attributes:
        name: The function.
        args: Positional arguments.
        kwargs: Keyword arguments.
        line: The line's number in the program (1: the first statement).
    """

    name: str
    args: tuple[Value, ...] = ()
    kwargs: tuple[tuple[str, Value], ...] = ()
    line: int = 1

    def arg(self, index: int, name: str, default: Value | None = None) -> Value | None:
        """Return an argument by position or keyword (``default`` when absent)."""
        named = dict(self.kwargs)
        if name in named:
            return named[name]
        return self.args[index] if index < len(self.args) else default


@dataclass(frozen=True, slots=True)
class Program:
    """A parsed program: its calls, or the errors that keep it from running.

    Attributes:
        text: The program as received.
        calls: Its calls, in order (empty when refused).
        errors: Why it cannot run (empty: it runs).
        received_ns: Monotonic time it arrived (``time.monotonic_ns``).
    """

    text: str
    calls: tuple[Call, ...] = ()
    errors: tuple[str, ...] = ()
    received_ns: int = 0
    announced: dict[str, str] = field(default_factory=dict)


class _RefusedError(ValueError):
    """An argument the lab cannot read."""


def _value(node: ast.expr) -> Value:
    """Return a literal argument.

    Raises:
        _RefusedError: Not a literal the subset has.
    """
    if isinstance(node, ast.Constant) and isinstance(node.value, int | float | str | bool):
        return node.value if isinstance(node.value, str | bool) else float(node.value)
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub | ast.UAdd):
        inner = _value(node.operand)
        if isinstance(inner, float):
            return -inner if isinstance(node.op, ast.USub) else inner
    if isinstance(node, ast.List):
        return _numbers(node.elts)
    if isinstance(node, ast.Subscript) and _is_name(node.value, "p"):
        elements = node.slice.elts if isinstance(node.slice, ast.Tuple) else [node.slice]
        return Pose(_numbers(elements))
    if isinstance(node, ast.Call) and _is_name(node.func, "get_actual_tcp_pose") and not node.args:
        return ActualPose()
    raise _RefusedError(ast.unparse(node))


def _is_name(node: ast.expr, name: str) -> bool:
    return isinstance(node, ast.Name) and node.id == name


def _numbers(nodes: Sequence[ast.expr]) -> tuple[float, ...]:
    values = [_value(node) for node in nodes]
    if not all(isinstance(v, float) for v in values):
        msg = "a list of numbers"
        raise _RefusedError(msg)
    return tuple(float(v) for v in values)  # type: ignore[arg-type]


def parse_call(line: str, number: int) -> Call | str:
    """Return the call on one line, or the error that refuses it."""
    try:
        tree = ast.parse(line.strip(), mode="eval").body
    except SyntaxError:
        return f"line {number}: not a function call: {line.strip()!r}"
    if not isinstance(tree, ast.Call) or not isinstance(tree.func, ast.Name):
        return f"line {number}: not a function call: {line.strip()!r}"
    name = tree.func.id
    if name not in FUNCTIONS:
        return f"line {number}: unknown function {name}()"
    try:
        args = tuple(_value(arg) for arg in tree.args)
        kwargs = tuple((kw.arg or "", _value(kw.value)) for kw in tree.keywords)
    except _RefusedError as err:
        return f"line {number}: {name}(): argument {err} is not a literal the virtual lab runs"
    return Call(name, args, kwargs, number)


def parse_program(text: str, received_ns: int = 0) -> Program:
    """Parse a program (``def name(): ... end`` or one line) into its calls, or its errors."""
    body = text.strip().split("\n")
    if body[0].startswith("def "):
        body = body[1:-1]
    calls: list[Call] = []
    errors: list[str] = []
    for number, raw in enumerate(body, start=1):
        if not raw.strip():
            continue
        parsed = parse_call(raw, number)
        if isinstance(parsed, str):
            errors.append(parsed)
        else:
            calls.append(parsed)
    if errors:
        return Program(text, (), tuple(errors), received_ns)
    return Program(text, tuple(calls), (), received_ns, _announcement(calls))


def _announcement(calls: Sequence[Call]) -> dict[str, str]:
    """Return the ``key=value`` pairs of the first ``textmsg("atikt: ...")`` (empty: none)."""
    for call in calls:
        message = call.arg(0, "s")
        if call.name == "textmsg" and isinstance(message, str) and message.startswith("atikt:"):
            pairs = (item.partition("=") for item in message.removeprefix("atikt:").split())
            return {key: value for key, _, value in pairs}
    return {}


def check_program(program: str) -> list[str]:
    """Return the program's errors (an unknown function, a line that is not a call)."""
    return list(parse_program(program).errors)


@dataclass(slots=True)
class ProgramSplitter:
    """Cut a byte stream into programs, with a bound on a program's size.

    A program is ``def name(): ... end`` (``end`` alone at column 0) or one line outside a
    definition. A program (or an unterminated definition) larger than ``limit`` bytes is
    refused: :meth:`feed` reports it once, and its bytes up to its ``end`` are dropped, so
    memory and time stay bounded whatever a client sends.
    """

    limit: int = MAX_PROGRAM_BYTES
    _pending: list[str] = field(default_factory=list)
    _pending_bytes: int = 0
    _current: list[str] | None = None
    _current_bytes: int = 0
    _skipping: bool = False
    _skip_line: bool = False

    def feed(self, text: str) -> tuple[list[str], list[str]]:
        """Add received text; return (complete programs, refusals: one line each)."""
        programs: list[str] = []
        refusals: list[str] = []
        lines = text.split("\n")
        for index, piece in enumerate(lines):
            if index == len(lines) - 1:  # no newline yet: held, within the bound
                if not self._skip_line:
                    self._pending.append(piece)
                    self._pending_bytes += len(piece)
                    if self._pending_bytes + self._current_bytes > self.limit:
                        refusals.extend(self._overflow())
                break
            if self._skip_line:
                self._skip_line = False
                continue
            line = "".join([*self._pending, piece])
            self._pending, self._pending_bytes = [], 0
            self._line(line, programs, refusals)
        return programs, refusals

    def _line(self, line: str, programs: list[str], refusals: list[str]) -> None:
        """Handle one complete line."""
        if self._skipping:
            if line.rstrip() == "end":
                self._skipping = False
            return
        if self._current is None:
            if line.startswith("def "):
                self._current, self._current_bytes = [line], len(line) + 1
            elif line.strip():
                programs.append(line + "\n")
            return
        self._current.append(line)
        self._current_bytes += len(line) + 1
        if line.rstrip() == "end":
            programs.append("\n".join(self._current) + "\n")
            self._current, self._current_bytes = None, 0
        elif self._current_bytes > self.limit:
            refusals.append(self._refusal(self._current_bytes))
            self._current, self._current_bytes, self._skipping = None, 0, True

    def _overflow(self) -> list[str]:
        """Drop a line growing past the bound (no newline in sight): refused once."""
        size = self._pending_bytes + self._current_bytes
        self._pending, self._pending_bytes, self._skip_line = [], 0, True
        if self._skipping:
            return []
        if self._current is not None:
            self._current, self._current_bytes, self._skipping = None, 0, True
        return [self._refusal(size)]

    def _refusal(self, size: int) -> str:
        return (
            f"URScript program refused: more than {self.limit} bytes ({size} so far) without "
            "its end; it is dropped (send programs below the bound, ended by 'end')"
        )

    @property
    def rest(self) -> str:
        """Return the incomplete text held (tests)."""
        head = "\n".join(self._current) + "\n" if self._current is not None else ""
        return head + "".join(self._pending)


def split_programs(text: str) -> tuple[list[str], str]:
    """Return the complete programs in ``text`` and the incomplete rest (no size bound)."""
    splitter = ProgramSplitter(limit=len(text) + 1)
    programs, _ = splitter.feed(text)
    return programs, splitter.rest
