"""`python -m import_all PKG...`: import every module of the packages and print one JSON object
{module: null, or the error it raised}. Run under the blocker of test_runtime_imports.py."""
import argparse
import importlib
import json
import pkgutil
import sys


def import_all(packages: list[str]) -> dict[str, str | None]:
    results: dict[str, str | None] = {}
    for name in packages:
        try:
            pkg = importlib.import_module(name)
        except Exception as e:  # reported, not raised: the test lists every failure at once
            results[name] = f"{type(e).__name__}: {e}"
            continue
        results[name] = None
        for info in pkgutil.walk_packages(pkg.__path__, prefix=f"{name}.", onerror=lambda n: None):
            try:
                importlib.import_module(info.name)
                results[info.name] = None
            except Exception as e:
                results[info.name] = f"{type(e).__name__}: {e}"
    return results


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("packages", nargs="+")
    ns = p.parse_args()
    print(json.dumps(import_all(ns.packages)))
    sys.exit(0)
