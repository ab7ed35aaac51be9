"""The packages declare what they use (issue #30): on a full ROS install ``rosdep install`` reads
package.xml, so a module that gldt_ros imports without declaring it works here (the venv has it)
and fails there. Imports are read from the sources with ``ast``, so the test needs no ROS."""

from __future__ import annotations

import ast
import re
import sys
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from support import MSG_DIR, REPO_ROOT

GLDT_ROS = REPO_ROOT / "src" / "gldt_ros"
GLDT_MSGS = MSG_DIR.parent

#: Top-level Python modules that are not ROS packages -> their rosdep key. ROS packages are
#: imported under their package name, which is also their key. Keys ending in -pip follow rosdep's
#: convention for packages installed from PyPI; gldt_core is this repository's pure-Python package
#: (docs/commands.md says how it is installed on a full ROS install).
PYTHON_KEYS = {
    "numpy": "python3-numpy",
    "cv2": "python3-opencv",
    "psutil": "python3-psutil",
    "yaml": "python3-yaml",
    "onnxruntime": "python3-onnxruntime-pip",
    "mcap": "python3-mcap-pip",
    "setuptools": "python3-setuptools",
    "gldt_core": "gldt_core",
}
#: ROS packages as far as this test knows them (a module neither here nor in PYTHON_KEYS fails
#: the test, so a new import gets a deliberate decision).
ROS_PACKAGES = {
    "rclpy",
    "rcl_interfaces",
    "builtin_interfaces",
    "std_msgs",
    "sensor_msgs",
    "geometry_msgs",
    "visualization_msgs",
    "diagnostic_msgs",
    "rosgraph_msgs",
    "ament_index_python",
    "launch",
    "launch_ros",
    "gldt_msgs",
}
#: Packages whose modules these must import anyway (the pipeline plays and records MCAP, the
#: detectors run onnxruntime, frames are decoded with OpenCV: all through gldt_core, and declared
#: so that rosdep installs them).
ALSO_DECLARED = {"python3-opencv", "python3-onnxruntime-pip", "python3-mcap-pip"}


def declared(package_xml: Path, *kinds: str) -> set[str]:
    root = ET.parse(package_xml).getroot()
    return {element.text.strip() for kind in kinds for element in root.iter(kind) if element.text}


def imported_modules(paths: list[Path]) -> dict[str, set[str]]:
    """Top-level module -> the files importing it (absolute imports only: relative ones are banned)."""
    modules: dict[str, set[str]] = {}
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                modules.setdefault(name.split(".")[0], set()).add(str(path.relative_to(REPO_ROOT)))
    return modules


def rosdep_key(module: str) -> str:
    if module in ROS_PACKAGES:
        return module
    if module in PYTHON_KEYS:
        return PYTHON_KEYS[module]
    raise KeyError(module)


def test_every_module_gldt_ros_imports_is_a_declared_dependency() -> None:
    runtime = sorted((GLDT_ROS / "gldt_ros").rglob("*.py")) + sorted((GLDT_ROS / "launch").glob("*.py"))
    package_xml = GLDT_ROS / "package.xml"
    exec_keys = declared(package_xml, "exec_depend", "depend")
    build_keys = declared(package_xml, "buildtool_depend", "build_depend", "depend")
    checks = [
        (imported_modules(runtime), exec_keys, "exec_depend"),
        (imported_modules([GLDT_ROS / "setup.py"]), build_keys, "buildtool_depend"),
    ]
    missing, unknown = [], []
    for modules, keys, kind in checks:
        for module, files in sorted(modules.items()):
            if module in sys.stdlib_module_names or module in ("__future__", "gldt_ros"):
                continue
            try:
                key = rosdep_key(module)
            except KeyError:
                unknown.append(f"{module} (imported by {sorted(files)[0]})")
                continue
            if key not in keys:
                missing.append(f"<{kind}>{key}</{kind}> for {module} (imported by {sorted(files)[0]})")
    assert not unknown, (
        "imports this test cannot map to a rosdep key; add them to PYTHON_KEYS or ROS_PACKAGES: " + ", ".join(unknown)
    )
    assert not missing, "src/gldt_ros/package.xml lacks:\n" + "\n".join(missing)
    assert ALSO_DECLARED <= exec_keys, f"src/gldt_ros/package.xml lacks {sorted(ALSO_DECLARED - exec_keys)}"


def test_the_scan_sees_the_imports_it_judges() -> None:
    """The check above could pass by reading nothing: it must find the graph's known imports."""
    modules = imported_modules(sorted((GLDT_ROS / "gldt_ros").rglob("*.py")))
    assert {"rclpy", "numpy", "gldt_core", "gldt_msgs", "rosgraph_msgs", "diagnostic_msgs"} <= set(modules)


def message_packages(msg_dir: Path) -> set[str]:
    """Packages the .msg files' fields refer to: ``pkg/Type`` (with or without ``/msg/``), and the
    built-in ``time``/``duration`` types, which are builtin_interfaces'."""
    packages: set[str] = set()
    for path in msg_dir.glob("*.msg"):
        for line in path.read_text(encoding="utf-8").splitlines():
            field = line.split("#", 1)[0].strip()
            if not field or "=" in field.split()[0]:
                continue
            type_name = re.sub(r"\[.*\]$", "", field.split()[0])
            if "/" in type_name:
                packages.add(type_name.split("/")[0])
            elif type_name in ("time", "duration"):
                packages.add("builtin_interfaces")
    return packages


def test_gldt_msgs_declares_every_package_its_messages_use() -> None:
    used = message_packages(MSG_DIR) - {"gldt_msgs"}
    assert {"std_msgs", "sensor_msgs", "builtin_interfaces"} <= used, f"the scan found only {sorted(used)}"
    package_xml = GLDT_MSGS / "package.xml"
    build, run = declared(package_xml, "depend", "build_depend"), declared(package_xml, "depend", "exec_depend")
    assert used <= build and used <= run, f"gldt_msgs/package.xml lacks {sorted(used - (build & run))}"
    cmake = (GLDT_MSGS / "CMakeLists.txt").read_text(encoding="utf-8")
    found = set(re.findall(r"find_package\((\w+) REQUIRED\)", cmake))
    match = re.search(r"DEPENDENCIES([^)]*)\)", cmake)
    assert match is not None, "rosidl_generate_interfaces has no DEPENDENCIES"
    dependencies = set(match.group(1).split())
    assert used <= found, f"CMakeLists.txt does not find_package {sorted(used - found)}"
    assert used <= dependencies, f"rosidl_generate_interfaces DEPENDENCIES lacks {sorted(used - dependencies)}"


@pytest.mark.parametrize("package", [GLDT_ROS, GLDT_MSGS], ids=["gldt_ros", "gldt_msgs"])
def test_package_xml_is_valid(package: Path) -> None:
    catkin_pkg = pytest.importorskip("catkin_pkg.package", reason="catkin_pkg comes with colcon")
    catkin_pkg.parse_package(str(package)).validate()


def test_python_is_not_capped_below_what_jazzy_runs_on() -> None:
    """ROS 2 Jazzy on Ubuntu 24.04 runs Python 3.12: gldt-core must install there."""
    from packaging.specifiers import SpecifierSet

    requires = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["requires-python"]
    specifier = SpecifierSet(requires)
    assert "3.11" in specifier and "3.12" in specifier and "3.13" in specifier, requires
    assert "3.10" not in specifier, requires
