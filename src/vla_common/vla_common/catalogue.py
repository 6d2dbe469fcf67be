"""The object and task catalogue: object classes, their tasks and their simulated shapes, as data.

The default catalogue (`data/catalogue.yaml`, the paper's five objects) ships with this package. A
lab's own YAML file `extends: default` (or another catalogue's path) to add or override objects, or
omits `extends` to replace it. Everything that names a class or a task — recorder, demonstrator,
training, controller, evaluation, the simulated scene — reads a `Catalogue`; nothing else lists them.
A task is parsed once where it enters (a flag, a service request, a file) into a `TaskSpec` and
travels as that object.

A catalogue's path may come from anyone who can set a node's parameter, so a file is read as
`vla_common.safe_yaml` reads one (a regular file of at most MAX_BYTES, no aliases, no duplicate
keys) and checked strictly: unknown keys, colours outside [0, 1], numbers that are not YAML numbers
are refused. Every defect is a CatalogueError naming the file and the key (`objects.spam.rgba[3]`),
never quoting the file's content.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vla_common.robot import HAND
from vla_common.safe_yaml import UnreadableError, YamlFileError, key_name, load_yaml

DEFAULT_PATH = Path(__file__).parent / "data" / "catalogue.yaml"
SHAPES = ("box", "cylinder")
STYLES = ("loaf", "rims", "band", "carton", "bottle", "labels")  # vla_sim.scene draws each
DEFAULT_PUSH_DISTANCE = 0.15
DEFAULT_LIFT_HEIGHT = 0.10     # m a `lift` demonstration raises the object (success needs 5 cm)
# The tasks with the hand (lift, pick_place_<direction>) need the object to fit the open hand at any
# yaw (the learned model sees no yaw): its footprint circle this much narrower than the hand's gap.
GRASP_CLEARANCE = 0.006
# What a catalogue file may hold; anything else is refused (a misspelt key would otherwise be ignored).
TOP_KEYS = ("extends", "objects", "task_sets")
REQUIRED_OBJECT_KEYS = ("shape", "size", "rgba", "mass", "friction")
OBJECT_KEYS = (*REQUIRED_OBJECT_KEYS, "accent_rgba", "style", "tasks")
TASK_OPTION_KEYS = ("distance",)
CLASS_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]{0,63}")
MAX_BYTES = 256 * 1024  # the default catalogue is 2.3 KB; hundreds of objects fit
MAX_EXTENDS = 8


COMPASS: dict[str, tuple[float, float]] = {
    "north": (1.0, 0.0),
    "south": (-1.0, 0.0),
    "west": (0.0, 1.0),
    "east": (0.0, -1.0),
    "north_west": (math.sqrt(0.5), math.sqrt(0.5)),
    "north_east": (math.sqrt(0.5), -math.sqrt(0.5)),
    "south_west": (-math.sqrt(0.5), math.sqrt(0.5)),
    "south_east": (-math.sqrt(0.5), -math.sqrt(0.5)),
}


def compass_vector(direction: str) -> np.ndarray:
    """Unit (x, y) vector of a compass direction name ("east", "south_west", "south-west", ...)."""
    key = direction.strip().lower().replace("-", "_").replace(" ", "_")
    if key not in COMPASS:
        raise ValueError(f"unknown compass direction {direction!r}; expected one of {sorted(COMPASS)}")
    return np.array(COMPASS[key])


@dataclass(frozen=True)
class ObjectSpec:
    """Shape and physics of one object class.

    shape: "box" (size = full x, y, z extents in the object's frame) or "cylinder" (size = radius,
    radius, height). rgba is the main colour; accent_rgba colours a decorative band/label.
    """

    shape: str
    size: tuple[float, float, float]
    rgba: tuple[float, float, float, float]
    mass: float
    friction: float
    accent_rgba: tuple[float, float, float, float] | None = None
    style: str = ""  # how the simulated scene decorates it (one of STYLES); "": by shape

    @property
    def height(self) -> float:
        return self.size[2]

    @property
    def footprint_radius(self) -> float:
        """Radius of the circle enclosing the object's footprint on the table (for layouts)."""
        if self.shape == "cylinder":
            return self.size[0]
        return 0.5 * math.hypot(self.size[0], self.size[1])

    @property
    def min_half_extent(self) -> float:
        """The smallest distance from the centre to the footprint's edge, over all directions."""
        if self.shape == "cylinder":
            return self.size[0]
        return 0.5 * min(self.size[0], self.size[1])


class CatalogueError(ValueError):
    """A catalogue file that cannot be used, or a class or task it does not define."""


class _UnreadableError(CatalogueError):
    """The catalogue file `path` cannot be opened as a regular file of the allowed size."""

    def __init__(self, message: str, path: Path, reason: str):
        super().__init__(message)
        self.path, self.reason = path, reason


@dataclass(frozen=True)
class TaskSpec:
    """One task: `kind` "push" (with a compass `direction`), "circle" (direction None), "lift"
    (grasp it and raise it by `distance`; direction None) or "pick_place" (grasp it and put it down
    `distance` away in the compass `direction`)."""

    name: str  # "<object class>/<action>"
    object_class: str
    kind: str
    direction: str | None
    distance: float = DEFAULT_PUSH_DISTANCE

    @property
    def action(self) -> str:
        return self.name.split("/", 1)[1]

    @property
    def uses_hand(self) -> bool:
        """The task grasps the object (the hand opens and closes during it)."""
        return self.kind in HAND_KINDS

    @property
    def direction_vector(self) -> np.ndarray:
        """Unit (x, y) push or placing direction in the world frame (push and pick_place tasks)."""
        if self.direction is None:
            raise ValueError(f"task {self.name} has no push direction")
        return compass_vector(self.direction)


@dataclass(frozen=True)
class Catalogue:
    """Object classes in index order, their specs and tasks, and named task lists."""

    objects: Mapping[str, ObjectSpec]
    tasks: Mapping[str, TaskSpec]
    task_sets: Mapping[str, tuple[str, ...]]
    sources: tuple[str, ...]  # the files it was read from, for error messages

    @property
    def classes(self) -> tuple[str, ...]:
        return tuple(self.objects)

    @property
    def where(self) -> str:
        return " + ".join(self.sources)

    def spec(self, class_id: str) -> ObjectSpec:
        try:
            return self.objects[class_id]
        except (KeyError, TypeError):
            raise CatalogueError(f"unknown object class {class_id!r}; known classes {list(self.classes)} "
                                 f"(defined in {self.where})") from None

    def class_index(self, class_id: str) -> int:
        self.spec(class_id)
        return self.classes.index(class_id)

    def task(self, text: str | TaskSpec) -> TaskSpec:
        """'bread/push_east' or 'bread:push_east' -> its TaskSpec; CatalogueError lists the known ones."""
        if isinstance(text, TaskSpec):
            return self.task(text.name)
        if not isinstance(text, str):
            raise CatalogueError(f"task must be a string like 'bread/push_east', got {text!r}")
        key = text.strip().replace(":", "/")
        parts = key.split("/")
        if len(parts) != 2 or not all(p.strip() for p in parts):
            raise CatalogueError(f"task {text!r} must look like '<object>/<action>', e.g. 'bread/push_east'; "
                                 f"known tasks {sorted(self.tasks)} (defined in {self.where})")
        obj, action = parts[0].strip(), _action_key(parts[1])
        self.spec(obj)
        name = f"{obj}/{action}"
        if name not in self.tasks:
            known = [t.action for t in self.tasks.values() if t.object_class == obj]
            raise CatalogueError(f"task {text!r}: {obj} has no task {action!r}; its tasks are {known} "
                                 f"(defined in {self.where})")
        return self.tasks[name]

    def task_set(self, name: str) -> list[TaskSpec]:
        """A named task list (`base`, `unseen`, ...) or one object's tasks (`<class>`)."""
        if name in self.task_sets:
            return [self.tasks[t] for t in self.task_sets[name]]
        if name in self.objects:
            return [t for t in self.tasks.values() if t.object_class == name]
        raise CatalogueError(f"unknown task set {name!r}; known sets {sorted(self.task_sets)} and the "
                             f"classes {list(self.classes)} (defined in {self.where})")

    def check_classes(self, classes, what: str) -> None:
        """CatalogueError naming both lists when `classes` (a detector's, a model's) are not all known."""
        unknown = [c for c in classes if c not in self.objects]
        if unknown:
            raise CatalogueError(f"{what} has classes {list(classes)}, the catalogue ({self.where}) has "
                                 f"{list(self.classes)}: {unknown} unknown")


def _action_key(text: str) -> str:
    return text.strip().lower().replace("-", "_").replace(" ", "_")


def _number(value, where: str, lo: float, hi: float, unit: str = "") -> float:
    """A YAML number (not a bool, not a string) in lo..hi."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CatalogueError(f"{where} must be a number{unit}")
    out = float(value)
    if not (math.isfinite(out) and lo <= out <= hi):
        raise CatalogueError(f"{where} must be a number{unit} in {lo:g}..{hi:g}")
    return out


def _numbers(value, n: int, where: str, lo: float, hi: float, unit: str = "") -> tuple[float, ...]:
    if not isinstance(value, list) or len(value) != n:
        raise CatalogueError(f"{where} must be a list of {n} finite numbers{unit}")
    return tuple(_number(v, f"{where}[{i}]", lo, hi, unit) for i, v in enumerate(value))


def _unknown_keys(body: Mapping, allowed: tuple[str, ...], where: str) -> None:
    unknown = [key_name(k) for k in body if k not in allowed]
    if unknown:
        raise CatalogueError(f"{where}: unknown key{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}; "
                             f"expected {', '.join(allowed)}")


HAND_KINDS = ("lift", "pick_place")


def _parse_task(obj: str, entry, where: str) -> TaskSpec:
    """One entry of an object's `tasks` (`where` names it: file, object, position)."""
    distance = None
    if isinstance(entry, Mapping):  # {push_east: {distance: 0.2}}
        if len(entry) != 1:
            raise CatalogueError(f"{where}: a task entry is a name or {{name: {{distance: m}}}}")
        (action, opts), = entry.items()
        if opts is not None:
            if not isinstance(opts, Mapping):
                raise CatalogueError(f"{where}: a task's options are a mapping, e.g. {{distance: 0.2}}")
            _unknown_keys(opts, TASK_OPTION_KEYS, where)
            if "distance" in opts:
                distance = _number(opts["distance"], f"{where}: distance", 0.01, 0.5, " (m)")
    else:
        action = entry
    if not isinstance(action, str):
        raise CatalogueError(f"{where}: a task is a name, 'circle' or push_<direction>")
    action = _action_key(action)
    name = f"{obj}/{action}"
    if action == "circle":
        return TaskSpec(name, obj, "circle", None)
    if action == "lift":
        return TaskSpec(name, obj, "lift", None, DEFAULT_LIFT_HEIGHT if distance is None else distance)
    for kind in ("push", "pick_place"):
        direction = action.removeprefix(kind + "_")
        if action.startswith(kind + "_") and direction in COMPASS:
            return TaskSpec(name, obj, kind, direction,
                            DEFAULT_PUSH_DISTANCE if distance is None else distance)
    raise CatalogueError(f"{where}: unknown task; a task is 'circle', 'lift', push_<direction> or "
                         f"pick_place_<direction> with a direction in {sorted(COMPASS)}")


def _parse_object(name: str, body, source: str) -> tuple[ObjectSpec, list[TaskSpec]]:
    where = f"{source}: objects.{name}"
    if not isinstance(body, Mapping):
        raise CatalogueError(f"{where} must be a mapping with {', '.join(REQUIRED_OBJECT_KEYS)}, tasks")
    _unknown_keys(body, OBJECT_KEYS, where)
    missing = [k for k in REQUIRED_OBJECT_KEYS if k not in body]
    if missing:
        raise CatalogueError(f"{where} lacks {', '.join(missing)}")
    shape = body["shape"]
    if shape not in SHAPES:
        raise CatalogueError(f"{where}.shape must be one of {', '.join(SHAPES)}")
    size = _numbers(body["size"], 3, f"{where}.size", 0.005, 0.5, " (m)")
    if shape == "cylinder" and size[0] != size[1]:
        raise CatalogueError(f"{where}.size of a cylinder is radius, radius, height (m): two equal radii")
    rgba = _numbers(body["rgba"], 4, f"{where}.rgba", 0.0, 1.0)
    accent = body.get("accent_rgba")
    accent = _numbers(accent, 4, f"{where}.accent_rgba", 0.0, 1.0) if accent is not None else None
    mass = _number(body["mass"], f"{where}.mass", 0.01, 5.0, " (kg)")
    friction = _number(body["friction"], f"{where}.friction", 0.05, 2.0)
    style = body.get("style", "")
    if style is None:
        style = ""
    if style not in ("", *STYLES):
        raise CatalogueError(f"{where}.style must be one of {', '.join(STYLES)} (or left out)")
    tasks = body.get("tasks")
    tasks = [] if tasks is None else tasks
    if not isinstance(tasks, list):
        raise CatalogueError(f"{where}.tasks must be a list, e.g. [push_east, circle]")
    spec = ObjectSpec(shape, size, rgba, mass, friction, accent_rgba=accent, style=style)
    own = [_parse_task(name, t, f"{where}.tasks[{i}]") for i, t in enumerate(tasks)]
    gap = HAND.max_width - GRASP_CLEARANCE
    for i, t in enumerate(own):
        if t.uses_hand and 2 * spec.footprint_radius > gap:
            raise CatalogueError(f"{where}.tasks[{i}]: {t.action} needs the object to fit the open hand at "
                                 f"any yaw: {2 * spec.footprint_radius:.3f} m across, at most {gap:.3f} m")
    names = [t.name for t in own]
    twice = [i for i, n in enumerate(names) if n in names[:i]]
    if twice:
        raise CatalogueError(f"{where}.tasks[{twice[0]}] repeats an earlier task of {name}")
    return spec, own


def _read(path: Path) -> dict:
    try:
        data = load_yaml(path, MAX_BYTES, "catalogue")
    except UnreadableError as err:
        raise _UnreadableError(str(err), path, err.reason) from None
    except YamlFileError as err:
        raise CatalogueError(str(err)) from None
    if not isinstance(data, Mapping) or not isinstance(data.get("objects"), Mapping):
        # its keys are not named: a file that is no catalogue may be anyone's
        raise CatalogueError(f"{path} is not a catalogue: a catalogue is a mapping with an 'objects' mapping")
    _unknown_keys(data, TOP_KEYS, str(path))
    return data


def load_catalogue(path: str | Path | None = None) -> Catalogue:
    """The catalogue in `path` (with what it extends), or the default one when `path` is None or ''."""
    if path in (None, "", "default"):
        return default_catalogue()
    if not isinstance(path, (str, Path)):
        raise CatalogueError("a catalogue is given by its path")
    return _load(_resolve(Path(path)), ())


@functools.lru_cache(maxsize=1)
def default_catalogue() -> Catalogue:
    return _load(DEFAULT_PATH, ())


def _load(path: Path, chain: tuple[Path, ...]) -> Catalogue:
    if path in chain:
        raise CatalogueError(f"{path}: 'extends' loops back to itself")
    if len(chain) >= MAX_EXTENDS:
        raise CatalogueError(f"{chain[0]}: 'extends' goes more than {MAX_EXTENDS} files deep")
    data = _read(path)
    base = data.get("extends")
    objects: dict[str, ObjectSpec] = {}
    tasks: dict[str, TaskSpec] = {}
    sets: dict[str, tuple[str, ...]] = {}
    sources: tuple[str, ...] = ()
    if base is not None:
        if not isinstance(base, str) or not base:
            raise CatalogueError(f"{path}: extends must be 'default' or the path of another catalogue")
        parent = default_catalogue() if base == "default" else _load_base(path, base, chain)
        objects, tasks, sets = dict(parent.objects), dict(parent.tasks), dict(parent.task_sets)
        sources = parent.sources
    for name, body in data["objects"].items():
        if not isinstance(name, str) or not CLASS_NAME.fullmatch(name):
            raise CatalogueError(f"{path}: objects: class {key_name(name)}: a class name is 1-64 letters, "
                                 "digits, '_' or '-'")
        spec, own = _parse_object(name, body, str(path))
        objects[name] = spec
        tasks = {k: t for k, t in tasks.items() if t.object_class != name} | {t.name: t for t in own}
    task_sets = data.get("task_sets")
    if task_sets is not None and not isinstance(task_sets, Mapping):
        raise CatalogueError(f"{path}: task_sets must be a mapping of names to lists of tasks")
    for set_name, names in (task_sets or {}).items():
        where = f"{path}: task_sets.{set_name}" if isinstance(set_name, str) else f"{path}: task_sets"
        if not isinstance(set_name, str) or not CLASS_NAME.fullmatch(set_name):
            raise CatalogueError(f"{where}: set {key_name(set_name)}: a set name is 1-64 letters, digits, "
                                 "'_' or '-'")
        if not isinstance(names, list):
            raise CatalogueError(f"{where} must be a list of tasks")
        resolved = []
        for i, t in enumerate(names):
            key = t.strip().replace(":", "/") if isinstance(t, str) else None
            if key not in tasks:
                raise CatalogueError(f"{where}[{i}] names a task that no object defines")
            resolved.append(key)
        sets[set_name] = tuple(resolved)
    return Catalogue(objects, tasks, sets, sources + (str(path),))


def _load_base(path: Path, base: str, chain: tuple[Path, ...]) -> Catalogue:
    """The catalogue `path` extends; one that cannot be opened is not named (the name is the file's
    content, and may not be a path at all)."""
    try:
        target = _resolve(path.parent / base)
    except CatalogueError:
        raise CatalogueError(f"{path}: extends: cannot read the catalogue it names") from None
    try:
        return _load(target, chain + (path,))
    except _UnreadableError as err:
        if err.path != target:
            raise
        raise CatalogueError(f"{path}: extends: cannot read the catalogue it names ({err.reason})") from None


def _resolve(path: Path) -> Path:
    try:
        return path.expanduser().resolve()
    except (OSError, RuntimeError, ValueError) as err:  # a symlink loop, a NUL byte
        raise CatalogueError(f"cannot read catalogue {path}: {type(err).__name__}") from None
