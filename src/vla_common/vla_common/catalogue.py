"""The object and task catalogue: object classes, their tasks and their simulated shapes, as data.

The default catalogue (`data/catalogue.yaml`, the paper's five objects) ships with this package. A
lab's own YAML file `extends: default` (or another catalogue's path) to add or override objects, or
omits `extends` to replace it. Everything that names a class or a task — recorder, demonstrator,
training, controller, evaluation, the simulated scene — reads a `Catalogue`; nothing else lists them.
A task is parsed once where it enters (a flag, a service request, a file) into a `TaskSpec` and
travels as that object.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

DEFAULT_PATH = Path(__file__).parent / "data" / "catalogue.yaml"
SHAPES = ("box", "cylinder")
DEFAULT_PUSH_DISTANCE = 0.15


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
    style: str = ""  # how the simulated scene decorates it (vla_sim.scene.STYLES); "": by shape

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


@dataclass(frozen=True)
class TaskSpec:
    """One task: `kind` "push" (with a compass `direction`) or "circle" (direction None)."""

    name: str  # "<object class>/<action>"
    object_class: str
    kind: str
    direction: str | None
    distance: float = DEFAULT_PUSH_DISTANCE

    @property
    def action(self) -> str:
        return self.name.split("/", 1)[1]

    @property
    def direction_vector(self) -> np.ndarray:
        """Unit (x, y) push direction in the world frame (push tasks only)."""
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


def _parse_task(obj: str, entry, source: str) -> TaskSpec:
    distance = DEFAULT_PUSH_DISTANCE
    if isinstance(entry, Mapping):  # {push_east: {distance: 0.2}}
        if len(entry) != 1:
            raise CatalogueError(f"{source}: {obj}: a task entry is a name or {{name: {{distance: m}}}}")
        (action, opts), = entry.items()
        distance = float((opts or {}).get("distance", distance))
    else:
        action = entry
    action = _action_key(str(action))
    name = f"{obj}/{action}"
    if action == "circle":
        return TaskSpec(name, obj, "circle", None)
    direction = action.removeprefix("push_")
    if not action.startswith("push_") or direction not in COMPASS:
        raise CatalogueError(f"{source}: {obj}: unknown task {action!r}; a task is 'circle' or "
                             f"push_<direction> with a direction in {sorted(COMPASS)}")
    if not (math.isfinite(distance) and 0.01 <= distance <= 0.5):
        raise CatalogueError(f"{source}: {name}: distance {distance} m is outside 0.01..0.5")
    return TaskSpec(name, obj, "push", direction, distance)


def _number_list(value, n: int, what: str) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise CatalogueError(f"{what} must be a list of {n} numbers, got {value!r}") from None
    if len(out) != n or not all(math.isfinite(v) for v in out):
        raise CatalogueError(f"{what} must be {n} finite numbers, got {value!r}")
    return out


def _parse_object(name: str, body, source: str) -> tuple[ObjectSpec, list[TaskSpec]]:
    where = f"{source}: object {name!r}"
    if not isinstance(body, Mapping):
        raise CatalogueError(f"{where} must be a mapping with shape, size, rgba, mass, friction, tasks")
    missing = [k for k in ("shape", "size", "rgba", "mass", "friction") if k not in body]
    if missing:
        raise CatalogueError(f"{where} lacks {missing}")
    shape = body["shape"]
    if shape not in SHAPES:
        raise CatalogueError(f"{where}: shape must be one of {SHAPES}, got {shape!r}")
    size = _number_list(body["size"], 3, f"{where}: size")
    if not all(0.005 <= s <= 0.5 for s in size) or (shape == "cylinder" and size[0] != size[1]):
        raise CatalogueError(f"{where}: size {size} must be 0.005..0.5 m (cylinder: radius, radius, height)")
    rgba = _number_list(body["rgba"], 4, f"{where}: rgba")
    accent = body.get("accent_rgba")
    accent = _number_list(accent, 4, f"{where}: accent_rgba") if accent is not None else None
    mass, friction = float(body["mass"]), float(body["friction"])
    if not (0.01 <= mass <= 5.0 and 0.05 <= friction <= 2.0):
        raise CatalogueError(f"{where}: mass {mass} kg must be 0.01..5, friction {friction} 0.05..2")
    tasks = body.get("tasks") or []
    if not isinstance(tasks, list):
        raise CatalogueError(f"{where}: tasks must be a list, e.g. [push_east, circle]")
    style = str(body.get("style", ""))
    spec = ObjectSpec(shape, size, rgba, mass, friction, accent_rgba=accent, style=style)
    return spec, [_parse_task(name, t, source) for t in tasks]


def _read(path: Path) -> dict:
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as err:
        raise CatalogueError(f"cannot read catalogue {path}: {err}") from None
    except yaml.YAMLError as err:
        raise CatalogueError(f"{path}: invalid YAML: {err}") from None
    if not isinstance(data, Mapping) or not isinstance(data.get("objects"), Mapping):
        raise CatalogueError(f"{path}: a catalogue is a mapping with an 'objects' mapping")
    unknown = set(data) - {"extends", "objects", "task_sets"}
    if unknown:
        raise CatalogueError(f"{path}: unknown keys {sorted(unknown)}; expected extends, objects, task_sets")
    return data


def load_catalogue(path: str | Path | None = None) -> Catalogue:
    """The catalogue in `path` (with what it extends), or the default one when `path` is None or ''."""
    if path in (None, "", "default"):
        return default_catalogue()
    return _load(Path(path).expanduser().resolve(), ())


@functools.lru_cache(maxsize=1)
def default_catalogue() -> Catalogue:
    return _load(DEFAULT_PATH, ())


def _load(path: Path, chain: tuple[Path, ...]) -> Catalogue:
    if path in chain:
        raise CatalogueError(f"{path}: 'extends' loops back to itself")
    data = _read(path)
    base = data.get("extends")
    objects: dict[str, ObjectSpec] = {}
    tasks: dict[str, TaskSpec] = {}
    sets: dict[str, tuple[str, ...]] = {}
    sources: tuple[str, ...] = ()
    if base:
        parent = default_catalogue() if base == "default" else _load((path.parent / base).resolve(),
                                                                     chain + (path,))
        objects, tasks, sets = dict(parent.objects), dict(parent.tasks), dict(parent.task_sets)
        sources = parent.sources
    for name, body in data["objects"].items():
        if not isinstance(name, str) or not name or "/" in name or ":" in name:
            raise CatalogueError(f"{path}: object class names are non-empty strings without '/' or ':', "
                                 f"got {name!r}")
        spec, own = _parse_object(name, body, str(path))
        objects[name] = spec
        tasks = {k: t for k, t in tasks.items() if t.object_class != name} | {t.name: t for t in own}
    for set_name, names in (data.get("task_sets") or {}).items():
        if not isinstance(names, list):
            raise CatalogueError(f"{path}: task set {set_name!r} must be a list of tasks")
        resolved = []
        for t in names:
            key = str(t).strip().replace(":", "/")
            if key not in tasks:
                raise CatalogueError(f"{path}: task set {set_name!r} names {t!r}, which no object defines")
            resolved.append(key)
        sets[str(set_name)] = tuple(resolved)
    return Catalogue(objects, tasks, sets, sources + (str(path),))
