"""Rewrite the wheel build machine's Python paths in the ROS wheels' CMake exports.

The ``ros-jazzy-*`` wheels were built against ``/opt/python/cp311-cp311``; their exported CMake
targets name that interpreter's include and site-packages folders, which CMake rejects
("includes non-existent path"). We substitute this venv's own paths. Rerunning is harmless:
files that no longer mention the old prefixes are left alone.

Usage: python scripts/fix_cmake_paths.py VENV
"""

from __future__ import annotations

import sys
import sysconfig
from pathlib import Path

OLD_INCLUDE = "/opt/python/cp311-cp311/include/python3.11"
OLD_SITE_PACKAGES = "/opt/python/cp311-cp311/lib/python3.11/site-packages"


def main(venv: Path) -> int:
    include_dir = sysconfig.get_paths()["include"]
    site_packages = sysconfig.get_paths()["purelib"]
    if not Path(include_dir, "Python.h").is_file():
        print(f"fix_cmake_paths: Python headers missing in {include_dir} (install python3.11-dev)")
        return 1
    changed = 0
    for cmake_file in (venv / "share").glob("*/cmake/**/*.cmake"):
        text = cmake_file.read_text(encoding="utf-8", errors="surrogateescape")
        if OLD_INCLUDE not in text and OLD_SITE_PACKAGES not in text:
            continue
        new_text = text.replace(OLD_INCLUDE, include_dir).replace(OLD_SITE_PACKAGES, site_packages)
        cmake_file.write_text(new_text, encoding="utf-8", errors="surrogateescape")
        changed += 1
    print(f"fix_cmake_paths: rewrote {changed} file(s) to {include_dir} and {site_packages}")
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]).resolve()))
