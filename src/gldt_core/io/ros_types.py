"""ROS 2 message types for bags and recordings, without a ROS installation.

Messages in MCAP files are (de)serialised with the ``rosbags`` typestore, which knows the stock
ROS 2 Jazzy types; the schemas :class:`gldt_core.io.mcap_file.McapWriter` writes come from it too.
This module adds the project's own ``gldt_msgs`` types, parsed from the very ``.msg`` files that
``colcon`` builds into the ROS package (``msg_defs/gldt_msgs/msg``), so the bag schema and the
live topics can never drift apart.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path
from typing import Any

MSG_PACKAGE = "gldt_msgs"
MSG_DIR_ENV = "GLDT_MSG_DIR"


def find_msg_dir() -> Path:
    """Locate ``msg_defs/gldt_msgs/msg``: ``$GLDT_MSG_DIR`` first, then above this source file.

    The package is installed editable from the repository, so the message definitions are found
    next to the sources.
    """
    override = os.environ.get(MSG_DIR_ENV)
    if override:
        path = Path(override)
        if not path.is_dir():
            raise FileNotFoundError(f"${MSG_DIR_ENV}={override} is not a directory of .msg files")
        return path
    for parent in Path(__file__).resolve().parents:
        candidate = parent / "msg_defs" / MSG_PACKAGE / "msg"
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(
        f"cannot find msg_defs/{MSG_PACKAGE}/msg above {__file__}; "
        f"set ${MSG_DIR_ENV} to the folder holding the gldt_msgs .msg files"
    )


def gldt_message_definitions(msg_dir: Path | None = None) -> dict[str, str]:
    """Map ``gldt_msgs/msg/<Name>`` to the text of its ``.msg`` file."""
    msg_dir = msg_dir or find_msg_dir()
    definitions = {
        f"{MSG_PACKAGE}/msg/{path.stem}": path.read_text(encoding="utf-8") for path in sorted(msg_dir.glob("*.msg"))
    }
    if not definitions:
        raise FileNotFoundError(f"no .msg files in {msg_dir}")
    return definitions


@lru_cache(maxsize=1)
def typestore() -> Any:
    """Return a rosbags ``Typestore`` with ROS 2 Jazzy types plus every ``gldt_msgs`` type."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    for name, text in gldt_message_definitions().items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store
