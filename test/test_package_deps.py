"""Every package.xml declares what its package's code imports and its launch files start, and nothing
of ours it does not use."""
import xml.etree.ElementTree as ET

import pytest
from package_deps import SRC, python_packages, required_keys

OURS = {p.name for p in SRC.iterdir() if (p / "package.xml").is_file()}


def declared(package: str) -> set[str]:
    root = ET.parse(SRC / package / "package.xml").getroot()
    return {e.text.strip() for tag in ("depend", "exec_depend") for e in root.iter(tag)}


@pytest.mark.parametrize("package", sorted(set(python_packages()) | {"vla_bringup"}))
def test_package_xml_matches_the_imports(package):
    need, have = required_keys(package), declared(package)
    assert need <= have, f"{package}/package.xml lacks {sorted(need - have)}"
    extra = {k for k in have - need if k in OURS}
    assert not extra, f"{package}/package.xml depends on {sorted(extra)} but never uses them"
