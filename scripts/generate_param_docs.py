"""Regenerate config/gldt.yaml and the README parameter table from the one schema.

Usage: python scripts/generate_param_docs.py   (run by `make docs`; a test checks both are current)
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src" / "gldt_ros"))

from gldt_ros.interface.params import default_yaml, markdown_table  # noqa: E402

TABLE_START = "| node | parameter |"
TABLE_END = "\n\n## Running the graph"


def main() -> int:
    (ROOT / "src" / "gldt_ros" / "config" / "gldt.yaml").write_text(default_yaml())
    readme_path = ROOT / "README.md"
    readme = readme_path.read_text()
    start, end = readme.index(TABLE_START), readme.index(TABLE_END)
    readme_path.write_text(readme[:start] + markdown_table() + readme[end:])
    print("regenerated src/gldt_ros/config/gldt.yaml and the README parameter table")
    return 0


if __name__ == "__main__":
    sys.exit(main())
