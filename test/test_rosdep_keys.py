"""`rosdep install --from-paths src --ignore-src` resolves on Ubuntu noble (Jazzy): every dependency key
of every package.xml is one of our packages, an upstream key we rely on (rosdep/upstream-keys.txt, the
keys rosdep 0.27 resolved against ros/rosdistro) or defined for noble in our rosdep/vla.yaml. Offline."""
import xml.etree.ElementTree as ET

import pytest
import yaml
from package_deps import SRC

ROOT = SRC.parent
TAGS = ("depend", "build_depend", "exec_depend", "test_depend", "buildtool_depend", "build_export_depend")
# The keys that rosdep 0.27 reported unresolvable for noble (issue 21): none may come back upstream-only.
UNRESOLVED_UPSTREAM = {
    "python3-torch-pip", "python3-safetensors-pip", "python3-onnx-pip", "python3-mcap-pip",
    "python3-mcap-ros2-support-pip", "python3-pylibfranka-pip", "python3-panda-python-pip",
    "example-robot-data",
}


def upstream_keys() -> set[str]:
    lines = (ROOT / "rosdep" / "upstream-keys.txt").read_text().splitlines()
    return {s for s in (ln.split("#")[0].strip() for ln in lines) if s}


def our_yaml() -> dict:
    return yaml.safe_load((ROOT / "rosdep" / "vla.yaml").read_text())


def package_keys() -> dict[str, set[str]]:
    keys = {}
    for xml in sorted(SRC.glob("*/package.xml")):
        root = ET.parse(xml).getroot()
        keys[xml.parent.name] = {e.text.strip() for t in TAGS for e in root.iter(t)}
    return keys


OURS = set(package_keys())


@pytest.mark.parametrize("package", sorted(OURS))
def test_every_key_resolves(package):
    known = upstream_keys() | set(our_yaml()) | OURS
    missing = package_keys()[package] - known
    assert not missing, f"{package}/package.xml: keys not upstream nor in rosdep/vla.yaml: {sorted(missing)}"


def test_our_yaml_defines_noble_for_each_key_and_shadows_nothing_upstream():
    data = our_yaml()
    for key, rule in data.items():
        installer = rule["ubuntu"]
        assert isinstance(installer, dict) and installer, key
        for spec in installer.values():
            assert spec["packages"], key
    assert not set(data) & upstream_keys(), "a key is both upstream and ours"
    assert UNRESOLVED_UPSTREAM - {"python3-torch-pip", "python3-mcap-ros2-support-pip"} <= set(data)


def test_keys_that_do_not_resolve_upstream_are_ours_or_unused():
    used = set().union(*package_keys().values())
    assert not (used & UNRESOLVED_UPSTREAM) - set(our_yaml())
    assert not UNRESOLVED_UPSTREAM & upstream_keys()


def test_the_source_line_is_documented():
    doc = (ROOT / "docs" / "install.md").read_text()
    assert "/etc/ros/rosdep/sources.list.d/" in doc and "rosdep/vla.yaml" in doc
