"""Which binding speaks to this robot: `open_driver` connects pylibfranka (FR3, protocol 10) or
panda-py (Panda, protocol 5), by name or, with `driver: auto`, from the protocol version the robot
answers with. It sits above both drivers so neither imports the other."""

from __future__ import annotations

from vla_panda_bridge.libfranka_driver import (
    DRIVERS,
    FATAL,
    PANDA_PY_PROTOCOL,
    PYLIBFRANKA_PROTOCOL,
    Driver,
    DriverSettings,
    PylibfrankaDriver,
    RobotError,
    server_version,
)
from vla_panda_bridge.libfranka_panda_py import PandaPyDriver


def open_driver(name: str, settings: DriverSettings) -> Driver:
    """A connected driver. `auto` tries pylibfranka and, if the robot answers with the Panda's
    protocol, panda-py; any other answer is a FATAL RobotError naming the version it saw."""
    if name not in DRIVERS:
        raise RobotError(FATAL, f"driver {name!r} is not one of {DRIVERS}")
    if name == "panda_py":
        return _connected(_panda_py(settings))
    if name == "pylibfranka":
        return _connected(_pylibfranka(settings))
    try:
        return _connected(_pylibfranka(settings))
    except RobotError as exc:
        version = server_version(exc.text)
        if version is None:
            raise
        if version == PANDA_PY_PROTOCOL:
            return _connected(_panda_py(settings))
        raise RobotError(FATAL, (
            f"driver auto: the robot at {settings.robot_ip} speaks server protocol {version}; "
            f"pylibfranka 0.21.3 speaks {PYLIBFRANKA_PROTOCOL} (FR3, system >= 5.9) and panda-py 1.1.1 "
            f"speaks {PANDA_PY_PROTOCOL} (Panda); install the libfranka binding for protocol {version} "
            f"(libfranka said: {exc.text})")) from exc


def _connected(driver: Driver) -> Driver:
    driver.connect()
    return driver


def _pylibfranka(settings: DriverSettings) -> Driver:
    try:
        return PylibfrankaDriver(settings)
    except ImportError as exc:
        raise RobotError(FATAL, f"driver pylibfranka: {exc} (pip install pylibfranka==0.21.3)") from exc


def _panda_py(settings: DriverSettings) -> Driver:
    try:
        return PandaPyDriver(settings)
    except ImportError as exc:
        raise RobotError(FATAL, f"driver panda_py: {exc} (pip install panda-python==1.1.1)") from exc
