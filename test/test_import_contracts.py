"""`make lint` runs the architecture contracts (.importlinter): they hold, and a violation breaks them."""
import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = sorted(p.name for p in (ROOT / "src").iterdir() if (p / p.name / "__init__.py").is_file())


def lint_imports(python_path: Path | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    if python_path is not None:
        env["PYTHONPATH"] = f"{python_path}{os.pathsep}{env.get('PYTHONPATH', '')}"
    return subprocess.run(["lint-imports", "--config", str(ROOT / ".importlinter"), "--no-cache"],
                          capture_output=True, text=True, env=env, cwd=ROOT, timeout=120)


def copy_packages(dest: Path) -> Path:
    for name in PACKAGES:
        shutil.copytree(ROOT / "src" / name / name, dest / name)
    return dest


def test_the_contracts_hold():
    r = lint_imports()
    assert r.returncode == 0, r.stdout + r.stderr
    assert "0 broken" in r.stdout


@pytest.mark.parametrize("module,line,contract", [
    ("vla_latent_controller/teleop.py", "import torch", "Runtime packages import no torch"),
    ("vla_latent_controller/teleop.py", "import rclpy", "Cores import no rclpy"),
    ("vla_operator/server.py", "import ray", "Only the evaluation and training packages import Ray"),
    ("vla_detector/inference.py", "import mujoco", "Only the bridge's MuJoCo backend imports the simulator"),
    ("vla_common/robot.py", "import vla_sim.sim", "Each layer imports only the layers below it"),
    ("vla_camera/source.py", "import vla_detector.decode", "Each layer imports only the layers below it"),
    ("vla_panda_bridge/libfranka_driver.py", "import vla_panda_bridge.libfranka_panda_py",
     "The libfranka drivers do not import each other"),
])
def test_a_deliberate_violation_breaks_its_contract(tmp_path, module, line, contract):
    copy = copy_packages(tmp_path)
    target = copy / module
    target.write_text(target.read_text() + f"\n{line}  # deliberate violation\n")
    r = lint_imports(copy)
    assert r.returncode != 0, r.stdout
    broken = r.stdout.split("Broken contracts")[-1]
    assert contract in broken, r.stdout
