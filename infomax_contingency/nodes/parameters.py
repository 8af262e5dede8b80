"""Parameter declaration with descriptors, ranges and one-line refusals.

Parameters are declared with a description and a range (``ros2 param describe`` shows
them); a bad value stops the node at start-up with one line naming the parameter, the
value and what is allowed (:class:`ConfigError`), never a traceback. An integer given
for a floating-point parameter (``-p window_s:=1``) is accepted.

A live set (``ros2 param set``) is checked by the same rule and refused with the same
message: rclpy checks a descriptor's type and range before any set-parameters callback,
so the check runs in a pre-set callback (:meth:`ParameterReader._check_first`), ahead
of rclpy's.

A parameter file's keys that no node declares are ignored by rcl without a word (a
misspelled key, a misspelled node section): ``parameter_files.undeclared_parameters``
names them, and ``runtime.run_nodes`` warns about them once its nodes are up.
"""

from __future__ import annotations

import array
import math
from collections.abc import Callable, Sequence
from contextlib import suppress
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from infomax_contingency.audio.bitsources import all_setting_specs, sources_with_setting
from infomax_contingency.audio.bitsources.base import SettingSpec
from infomax_contingency.core.model import ModelParams, ParameterError


class ConfigError(ValueError):
    """A parameter value the node cannot work with; the message says what is allowed."""


def _range_text(low: float, high: float, unit: str) -> str:
    return f"a number in [{low:g}, {high:g}]" + (f" {unit}" if unit else "")


READ_ONLY_REASON = "parameter '{}' is read-only while the node runs; restart the node to change it"
"""Why a parameter the node reads once at start-up cannot be set (``.format(name)``)."""

SIM_TIME_REASON = (
    "parameter 'use_sim_time' = True is not allowed: these nodes run on the system clock"
    " and nothing in the package publishes /clock (their timers would stop); leave it false"
)
"""Why ``use_sim_time`` (rclpy's, every node's) cannot be true, at start-up or live."""


class ParameterReader:
    """Declares a node's parameters with descriptors and checks their values."""

    def __init__(self, node: Node) -> None:
        self._node = node
        self.node = node
        """The node whose parameters these are."""
        self._coercers: dict[str, Callable[[Any], Any]] = {}
        self._appliers: dict[str, Callable[[Any], None]] = {}
        self._checks: dict[str, Callable[[Any], None]] = {}
        self._refusal = ""
        self._in_set: dict[str, Any] = {}
        """The live values of the set being checked, coerced (see :meth:`in_set`)."""
        self.known: set[str] = set()
        """Names the node takes in another configuration though it does not declare them
        now (another bit source's settings): not a misspelling (``undeclared_parameters``)."""
        if node.get_parameter("use_sim_time").value is True:
            raise ConfigError(SIM_TIME_REASON)
        node.add_pre_set_parameters_callback(self._check_first)
        node.add_on_set_parameters_callback(self._on_set)

    def live(
        self,
        name: str,
        on_change: Callable[[Any], None],
        check: Callable[[Any], None] | None = None,
    ) -> None:
        """Let the declared parameter ``name`` change at run time through ``on_change``.

        Only for parameters declared with ``read_only=False``. ``check(value)`` (optional)
        raises :class:`ConfigError` for a value that its start-up rule allows but the
        node's other parameters do not (the same message as at start-up); it reads those
        with :meth:`in_set`, so that parameters set together are judged together.
        """
        self._appliers[name] = on_change
        if check is not None:
            self._checks[name] = check

    def in_set(self, name: str) -> Any:
        """``name``'s value in the set being checked, else its current value.

        For a check that compares parameters (posture_node: ``bored_below`` below
        ``attentive_above``): an atomic set of both is judged by the pair it sets, not
        one new value against the other's old one.
        """
        return self._in_set[name] if name in self._in_set else self._node.get_parameter(name).value

    @property
    def the_set(self) -> dict[str, Any]:
        """The live values of the set being checked or applied (coerced; empty between sets)."""
        return dict(self._in_set)

    def _check_first(self, parameters: list[Parameter]) -> list[Parameter]:
        """Check a set by the start-up rules before rclpy checks the descriptors.

        rclpy checks a descriptor's type and range (with its own wording) before any
        set-parameters callback runs, so a refusal would never carry this node's message.
        This pre-set callback runs first: a live parameter's value is coerced as at
        start-up (an integer for a floating-point parameter is accepted); a value the
        start-up rule refuses is replaced by the parameter's current value (which passes
        the descriptor) and the refusal is kept, to be returned by :meth:`_on_set`, so the
        set fails with the start-up message and nothing changes. A name the node does not
        declare is refused so too (:meth:`_undeclared_reason`; rclpy names none), with every
        read-only name of the set (rclpy would name one); so is ``use_sim_time`` true
        (:data:`SIM_TIME_REASON`); else those pass unchanged.
        """
        self._refusal = ""
        self._in_set = _live_values(parameters, self._coercers, self._appliers)
        checked = []
        undeclared = [p.name for p in parameters if not self._node.has_parameter(p.name)]
        read_only = [p.name for p in parameters if p.name not in undeclared
                     and self._node.describe_parameter(p.name).read_only] if undeclared else []
        if undeclared:
            self._refusal = "; ".join([self._undeclared_reason(name) for name in undeclared]
                                      + [READ_ONLY_REASON.format(name) for name in read_only])
        for parameter in parameters:
            sim_time = parameter.name == "use_sim_time" and parameter.value is True
            if sim_time:
                self._refusal = self._refusal or SIM_TIME_REASON
            if parameter.name in undeclared or parameter.name in read_only or sim_time:
                checked.append(self._stand_in())
                continue
            coerce = self._coercers.get(parameter.name)
            if coerce is None or parameter.name not in self._appliers:
                checked.append(parameter)
                continue
            try:
                value = coerce(parameter.value)
                self._checks.get(parameter.name, lambda _value: None)(value)
            except ConfigError as error:
                self._refusal = self._refusal or str(error)
                checked.append(self._node.get_parameter(parameter.name))
                continue
            checked.append(Parameter(parameter.name, value=value))
        self._in_set = {}
        return checked

    def _undeclared_reason(self, name: str) -> str:
        """Why ``name`` cannot be set: another bit source's setting, or no parameter at all."""
        node = self._node.get_fully_qualified_name()
        owners = sources_with_setting(name) if name in self.known else ()
        if not owners:
            return (f"parameter '{name}' is not a parameter of {node} (`ros2 param list"
                    f" {node}` lists them)")  # fmt: skip
        running = self._node.get_parameter("bit_source").value
        short = self._node.get_name()
        return (f"parameter '{name}' is a setting of bit_source {' or '.join(owners)}, and"
                f" {node} runs bit_source {running}: not a parameter of it (start the node with"
                f" bit_source {owners[0]} and {name} in its parameter file, or after the file"
                f" -p {short}:bit_source:={owners[0]} -p {short}:{name}:=...)")  # fmt: skip

    def _stand_in(self) -> Parameter:
        """``use_sim_time`` (every node's, never read-only) at its value: holds a name's place.

        rclpy refuses a set that holds an undeclared name before any set callback, with
        an answer that names no parameter; with this in its place the set reaches
        :meth:`_on_set` (the set callback rclpy calls first), which refuses it with
        :meth:`_undeclared_reason`'s line.
        """
        return self._node.get_parameter("use_sim_time")

    def _on_set(self, parameters: list[Parameter]) -> SetParametersResult:
        """Check every parameter of a set by its start-up rule; apply and log them all."""
        if self._refusal:
            reason, self._refusal = self._refusal, ""
            return SetParametersResult(successful=False, reason=reason)
        values = {}
        self._in_set = _live_values(parameters, self._coercers, self._appliers)
        try:
            for parameter in parameters:
                coerce = self._coercers.get(parameter.name)
                if coerce is None:  # being declared, or not one of ours (use_sim_time)
                    continue
                if parameter.name not in self._appliers:
                    return SetParametersResult(successful=False,
                                               reason=READ_ONLY_REASON.format(parameter.name))
                values[parameter.name] = coerce(parameter.value)
                self._checks.get(parameter.name, lambda _value: None)(values[parameter.name])
            for name, value in values.items():  # an applier may read the set too
                self._appliers[name](value)
                self._node.get_logger().info(f"parameter '{name}' set to {value!r}")
        except ConfigError as error:
            return SetParametersResult(successful=False, reason=str(error))
        finally:
            self._in_set = {}
        return SetParametersResult(successful=True)

    def _declare(
        self,
        name: str,
        default: Any,
        descriptor: ParameterDescriptor,
        coerce: Callable[[Any], Any],
        allowed: str,
    ) -> Any:
        """Declare; on a value ROS refuses (type or range), explain it as a ConfigError."""
        value = self._declare_checked(name, default, descriptor, coerce, allowed)
        self._coercers[name] = coerce
        return value

    def _declare_checked(
        self,
        name: str,
        default: Any,
        descriptor: ParameterDescriptor,
        coerce: Callable[[Any], Any],
        allowed: str,
    ) -> Any:
        descriptor.name = name
        descriptor.additional_constraints = allowed
        try:
            return coerce(_given(self._node.declare_parameter(name, default, descriptor).value))
        except (InvalidParameterTypeException, InvalidParameterValueException):
            pass
        loose = ParameterDescriptor(name=name, dynamic_typing=True)
        raw = _given(self._node.declare_parameter(name, default, loose).value)
        self._node.undeclare_parameter(name)
        value = coerce(raw)  # raises ConfigError when the value cannot be used at all
        try:
            self._node.declare_parameter(name, value, descriptor, ignore_override=True)
        except (InvalidParameterTypeException, InvalidParameterValueException):
            raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}") from None
        return value

    def number(
        self,
        name: str,
        default: float,
        description: str,
        low: float,
        high: float,
        unit: str = "",
        read_only: bool = True,
    ) -> float:
        """A floating-point parameter in ``[low, high]``."""
        allowed = _range_text(low, high, unit)

        def coerce(raw: Any) -> float:
            if isinstance(raw, bool) or not isinstance(raw, int | float):
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            value = float(raw)
            if not math.isfinite(value) or not low <= value <= high:
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            return value

        descriptor = ParameterDescriptor(
            description=description,
            read_only=read_only,
            floating_point_range=[FloatingPointRange(from_value=low, to_value=high, step=0.0)],
        )
        return self._declare(name, float(default), descriptor, coerce, allowed)

    def integer(
        self,
        name: str,
        default: int,
        description: str,
        low: int,
        high: int,
        read_only: bool = True,
    ) -> int:
        """An integer parameter in ``[low, high]``."""
        allowed = f"a whole number in [{low}, {high}]"

        def coerce(raw: Any) -> int:
            if isinstance(raw, bool) or not isinstance(raw, int) or not low <= raw <= high:
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            return int(raw)

        descriptor = ParameterDescriptor(
            description=description,
            read_only=read_only,
            integer_range=[IntegerRange(from_value=low, to_value=high, step=1)],
        )
        return self._declare(name, int(default), descriptor, coerce, allowed)

    def flag(
        self, name: str, default: bool, description: str, read_only: bool = True
    ) -> bool:
        """A boolean parameter."""
        allowed = "true or false"

        def coerce(raw: Any) -> bool:
            if not isinstance(raw, bool):
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            return raw

        return self._declare(
            name,
            bool(default),
            ParameterDescriptor(description=description, read_only=read_only),
            coerce,
            allowed,
        )

    def text(
        self,
        name: str,
        default: str,
        description: str,
        choices: Sequence[str] | None = None,
        read_only: bool = True,
    ) -> str:
        """A string parameter, optionally one of ``choices``."""
        allowed = f"one of {', '.join(choices)}" if choices else "a string"

        def coerce(raw: Any) -> str:
            if not isinstance(raw, str) or (choices and raw not in choices):
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            return raw

        return self._declare(
            name,
            str(default),
            ParameterDescriptor(description=description, read_only=read_only),
            coerce,
            allowed,
        )

    def texts(
        self, name: str, default: Sequence[str], description: str, read_only: bool = True
    ) -> list[str]:
        """A non-empty list of strings."""
        allowed = "a non-empty list of strings"

        def coerce(raw: Any) -> list[str]:
            if not isinstance(raw, list | tuple) or not raw:
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            if not all(isinstance(item, str) and item for item in raw):
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            return list(raw)

        return self._declare(
            name,
            list(default),
            ParameterDescriptor(description=description, read_only=read_only),
            coerce,
            allowed,
        )

    def numbers(
        self, name: str, default: Sequence[float], description: str, read_only: bool = True
    ) -> list[float]:
        """A non-empty list of finite numbers."""
        allowed = "a non-empty list of finite numbers"

        def coerce(raw: Any) -> list[float]:
            # A set through the parameter services hands a double array as array('d').
            if not isinstance(raw, list | tuple | array.array) or not raw:
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            if not all(
                isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                for v in raw
            ):
                raise ConfigError(f"parameter '{name}' = {raw!r} is not allowed: {allowed}")
            return [float(v) for v in raw]

        return self._declare(
            name,
            [float(v) for v in default],
            ParameterDescriptor(description=description, read_only=read_only),
            coerce,
            allowed,
        )

    def given(self, name: str) -> Any:
        """The value given for ``name`` (parameter file, ``-p``), declared or not; None if none.

        rcl hands a node every value meant for it; one the node does not declare is
        otherwise dropped without a word.
        """
        override = getattr(self._node, "_parameter_overrides", {}).get(name)
        return None if override is None else override.value

    def declared(self, spec: SettingSpec) -> Any:
        """The parameter a bit source declares (:class:`SettingSpec`): same name, range, text.

        The other sources' settings become :attr:`known`: a file may set them for a switch
        of ``bit_source`` (config/robot.yaml does).
        """
        self.known.update(other.name for other in all_setting_specs())
        read_only = not spec.live
        if isinstance(spec.default, str):
            return self.text(spec.name, spec.default, spec.description, spec.choices, read_only)
        if isinstance(spec.default, int):
            return self.integer(spec.name, spec.default, spec.description, int(spec.low),
                                int(spec.high), read_only)  # fmt: skip
        return self.number(spec.name, spec.default, spec.description, spec.low, spec.high,
                           spec.unit, read_only)  # fmt: skip

    def model(self) -> ModelParams:
        """The ``params`` parameter: a named model parameter set or a YAML file."""
        name = self.text(
            "params",
            "robot",
            "Model parameters (MODEL.md): a named set (robot, paper) or a YAML file holding"
            " dt, ts1, ts2, ta1, ta2, pi and optionally the Beta priors b11 .. b32",
        )
        try:
            params = ModelParams.load(name)
        except ParameterError as error:
            raise ConfigError(f"parameter 'params' = {name!r}: {error}") from None
        self._refuse_another_window(params.dt)
        return params

    def _refuse_another_window(self, dt: float) -> None:
        """Refuse a ``window_s`` given for the node that is not the model's dt (seconds).

        The window (one step) is always the model's dt; ``window_s`` is no parameter. A
        parameter file that still sets it to dt works; another value would silently be
        another window than the one meant, so the node stops and says so.
        """
        value = self.given("window_s")
        if value is None:
            return
        if isinstance(value, int | float) and not isinstance(value, bool):
            if abs(value - dt) <= 1e-9:
                return
            shown = f"{value:g} s"
        else:
            shown = repr(value)
        raise ConfigError(
            f"parameter 'window_s' = {shown} differs from the model's dt = {dt:g} s (parameter"
            " 'params'): one window is one step of the model; remove window_s"
        )



def _live_values(parameters: list[Parameter], coercers: dict[str, Callable[[Any], Any]],
                 appliers: dict[str, Callable[[Any], None]]) -> dict[str, Any]:  # fmt: skip
    """The coerced value of each live parameter of a set (one its rule refuses left out)."""
    values = {}
    for parameter in parameters:
        coerce = coercers.get(parameter.name)
        if coerce is not None and parameter.name in appliers:
            with suppress(ConfigError):  # refused by its own rule in the check
                values[parameter.name] = coerce(parameter.value)
    return values


def device_parameter(node: Node, what: str) -> str:
    """Declare and read the ``device`` parameter: ``""``, an index or a part of a name.

    ``-p device:=3`` arrives as an integer, ``-p device:=USB`` as a string; both are
    accepted (the parameter is dynamically typed) and returned as text, which
    :func:`~infomax_contingency.audio.devices.resolve_device` understands.
    """
    allowed = "empty (the system default), a device index, or a part of a device name"
    descriptor = ParameterDescriptor(
        name="device",
        description=f"{what}: empty = the system default, an index, or a part of its name"
        " (first match; `infomax-contingency devices` lists them)",
        additional_constraints=allowed,
        dynamic_typing=True,
        read_only=True,
    )
    value = node.declare_parameter("device", "", descriptor).value
    if isinstance(value, bool) or not isinstance(value, int | str):
        raise ConfigError(f"parameter 'device' = {value!r} is not allowed: {allowed}")
    return str(value).strip()


def _given(value: Any) -> Any:
    """A declared parameter's value as given (an empty list where rclpy says None).

    rcl reads an empty list (``-p NAME:=[]``, ``NAME: []`` in a file) as a value of no
    type, which rclpy hands over as None.
    """
    return [] if value is None else value
