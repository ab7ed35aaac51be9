"""``pipeline`` (``ros2 run gldt_ros pipeline``): start the GL-DT node graph, optionally replay a bag
into it and record its outputs.

Like a launch file, it starts the nodes of the graph (:data:`gldt_ros.interface.graph.NODES`) in
processes placed by ``--processes`` (:data:`gldt_ros.interface.graph.PROCESS_LAYOUTS`): by default
the nodes a LOCAL frame passes through share one process and the global detector has its own;
``--processes one-process`` puts all five in one, ``--processes per-node`` gives each node its own;
``--in-process`` runs all of them in this process's executor, which is handy for debugging and
profiling. With ``--bag`` it plays the bag's camera, camera_info and ground-truth topics into the
graph, either at the bag's pace times ``--rate`` or in ``--lockstep``: frame t+1 is only published
after ``/gldt/tracks`` has answered frame t, which makes a replay deterministic
(:class:`gldt_ros.launcher.replay.GraphDriver` plays and records). ``--record OUT.mcap`` writes
every output topic, with its type, to an MCAP file. The run ends at the bag's end or on Ctrl-C, and
the child nodes are stopped with SIGINT (then SIGTERM/SIGKILL if they hang). While the graph runs,
a node that dies is restarted (:class:`NodeProcesses`), and so is one that stops answering: silent
on ``/diagnostics`` for 1.5 s, it is killed and restarted (:mod:`gldt_ros.launcher.heartbeat`).
Every child dies with ``pipeline``: a ``kill -9`` of it sends them SIGTERM (Linux parent-death
signal, :func:`spawn`), and the recording keeps everything up to the last second
(:class:`gldt_core.io.mcap_file.McapWriter`).

The player restamps the bag's frames to the time the replay starts (``--keep-bag-stamps`` keeps
them), sends each frame's camera_info first, and publishes ``/clock``
(:mod:`gldt_ros.launcher.replay`). It reads a damaged bag as the offline reader does: a forward
scan that needs no summary, a message that cannot be read skipped with one warning, and
everything before damage replayed. Before the first frame it sends a warm-up frame through the
graph (start-up: not recorded, not counted), and at the end one summary line: frames sent, the
rate achieved against the bag's, frames answered (counted from the tracks received; how many by
prediction, for frames skipped by plan or undecodable), latency p50/p99.

Exit status: 0 when every frame of the bag was replayed and answered (frames the graph skipped by
plan while the global detector was busy are answered, by prediction: the documented degradation);
3 when frames were lost (unreadable messages skipped, images the graph could not decode, a bag
that ends in damage) or unanswered (lockstep frames given up, paced frames sent but never
answered), said in one line after the summary; 1 when the graph failed (a node that would not
start, died for good or did not stop cleanly).

ROS arguments after ``--ros-args`` (remaps, ``-p name:=value``,
``--params-file``, ``--log-level``) go to every node and to the player, as ``ros2 launch`` would
hand them on: ``pipeline --bag B --ros-args -p use_sim_time:=true -r camera/image_raw:=/cam/image``.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from gldt_ros.interface.graph import DEFAULT_PROCESS_LAYOUT, NODES, PROCESS_LAYOUTS, default_params_file, group_label
from gldt_ros.launcher.heartbeat import Heartbeats
from gldt_ros.runtime.dds_profile import profile_for_children, use_frames_profile_if_shipped, use_graph_dds_profile
from gldt_ros.runtime.executor import EXECUTOR_CHOICES, EXECUTOR_ENV, background_executor, executor_kind
from gldt_ros.runtime.heap_trim import DEFAULT_PERIOD_S, HEAP_TRIM_PERIOD_ENV, start_heap_trimming
from gldt_ros.runtime.node_group import group_json
from gldt_ros.runtime.shm_cleanup import MIN_AGE_S, remove_dead_segments
from gldt_ros.runtime.stack_dump import STACK_DUMP_SIGNAL
from gldt_ros.runtime.teardown_limit import TEARDOWN_LIMIT_S, TEARDOWN_TIMEOUT_EXIT

#: Memory settings for the node processes, applied where the user has not set them. A node handles
#: buffers of a MiB or more every frame (a decoded 1080p frame is 6 MiB). With glibc's defaults
#: they come from the heap, which only shrinks from its top, so resident memory climbs in steps
#: over a long run (``python -m gldt_ros.bench.soak`` shows it). Each node therefore calls
#: malloc_trim every second (:mod:`gldt_ros.runtime.heap_trim`), which returns free pages from
#: anywhere in the heap, and two arenas bound the per-thread growth. A fixed mmap threshold
#: (``MALLOC_MMAP_THRESHOLD_``) would bound the heap too, but gives every such buffer fresh pages
#: to fault in on every frame, which slows the whole replay down (``docs/experiment-log.md``).
NODE_MALLOC_SETTINGS = {"MALLOC_ARENA_MAX": "2", HEAP_TRIM_PERIOD_ENV: f"{DEFAULT_PERIOD_S:g}"}


#: The largest ROS_DOMAIN_ID whose DDS ports fit in 16 bits (ROS 2's documented limit on Linux).
MAX_DOMAIN_ID = 232
#: Where a replay picks its own domain: above the ids people and tests usually set by hand.
OWN_DOMAIN_IDS = range(101, MAX_DOMAIN_ID + 1)


def domain_in_use(domain_id: int) -> bool:
    """Whether a DDS participant on this host holds ``domain_id``: the first participant of a
    domain binds its unicast discovery port (RTPS: 7400 + 250 * domain + 10) exclusively."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.bind(("0.0.0.0", 7400 + 250 * domain_id + 10))
        except OSError:
            return True
    return False


def choose_domain(args: argparse.Namespace) -> str | None:
    """Set this process's ``ROS_DOMAIN_ID`` (the nodes inherit it) and say why, in one line:
    ``--domain-id`` where given; else the environment's where set, or for a live graph (it must
    meet the camera); else, for a ``--bag`` replay, a free id of its own picked at random from
    :data:`OWN_DOMAIN_IDS`."""
    if args.domain_id is not None:
        os.environ["ROS_DOMAIN_ID"] = str(args.domain_id)
        return f"pipeline: on ROS_DOMAIN_ID {args.domain_id} (--domain-id)"
    if os.environ.get("ROS_DOMAIN_ID", "").strip() or args.bag is None:
        return None
    import random

    candidates = list(OWN_DOMAIN_IDS)
    random.SystemRandom().shuffle(candidates)
    chosen = next((d for d in candidates if not domain_in_use(d)), candidates[0])
    os.environ["ROS_DOMAIN_ID"] = str(chosen)
    return (
        f"pipeline: isolated on ROS_DOMAIN_ID {chosen}, free and its own "
        "(set ROS_DOMAIN_ID or --domain-id to join another graph)"
    )


def node_environment(tune_malloc: bool, executor: str | None = None) -> dict[str, str]:
    """The environment node processes start with: this one's, plus :data:`NODE_MALLOC_SETTINGS`
    where ``tune_malloc`` and the user has not set them, the shipped small-segment DDS profile
    where this process switched to its frames twin (each node picks its own), and ``executor``
    (:mod:`gldt_ros.runtime.executor`) where given."""
    env = profile_for_children(dict(os.environ))
    if executor is not None:
        env[EXECUTOR_ENV] = executor
    if tune_malloc:
        for key, value in NODE_MALLOC_SETTINGS.items():
            env.setdefault(key, value)
    return env


def split_ros_args(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """``(pipeline's own arguments, the ROS arguments)``: every ``--ros-args`` block up to a ``--``
    or the end, as rcl reads them, joined into one ``--ros-args ...`` list (empty without any)."""
    own: list[str] = []
    ros: list[str] = []
    inside = False
    for token in argv:
        if token == "--ros-args":
            inside = True
        elif inside and token == "--":
            inside = False
        elif inside:
            ros.append(token)
        else:
            own.append(token)
    return own, (["--ros-args", *ros] if ros else [])


#: Remaps the graph cannot take from the command line: they would give all five nodes one name,
#: or move them out of the namespace ``pipeline`` waits for (``--namespace`` does that).
_REFUSED_REMAP = re.compile(r"^(?:[^:=]+:)?(?:__node|__name|__ns):=")


def check_ros_args(ros_args: Sequence[str]) -> str | None:
    """Why ``ros_args`` cannot go to every node, or ``None`` when they can."""
    for flag, value in zip(ros_args, ros_args[1:]):
        if flag in ("-r", "--remap") and _REFUSED_REMAP.match(value):
            return f"--ros-args {flag} {value}: node names are fixed; use --namespace for the graph's namespace"
    return None


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    own, ros_args = split_ros_args(list(sys.argv[1:] if argv is None else argv))
    parser = argparse.ArgumentParser(
        prog="pipeline",
        description=__doc__.split("\n\n")[0],
        epilog="ROS arguments for every node follow --ros-args (remaps, -p name:=value, --params-file, --log-level).",
    )
    parser.add_argument("--bag", type=Path, help="rosbag2 MCAP (file or folder) to replay into the graph")
    parser.add_argument("--record", type=Path, help="write the graph's outputs to this MCAP file")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=float, default=1.0, help="replay speed factor (default 1.0)")
    pace.add_argument("--lockstep", action="store_true", help="publish frame t+1 only after tracks for frame t")
    parser.add_argument(
        "--keep-bag-stamps",
        action="store_true",
        help="replay the bag's header stamps as recorded (default: moved to the replay's start time, "
        "intervals kept, so a planner's staleness check accepts them)",
    )
    parser.add_argument("--params", type=Path, default=None, help="ROS parameter YAML (default: config/gldt.yaml)")
    parser.add_argument("--namespace", default="", help="namespace of the graph (one per camera)")
    placement = parser.add_mutually_exclusive_group()
    placement.add_argument("--in-process", action="store_true", help="run all nodes in this process")
    placement.add_argument(
        "--processes",
        choices=list(PROCESS_LAYOUTS),
        default=DEFAULT_PROCESS_LAYOUT,
        help="how the nodes share processes: grouped, the frame buffer, scheduler, tracker and local "
        "detector in one and the global detector in its own (no process hop within a LOCAL frame; a "
        "group restarts as a whole); one-process, all five in one (the least transport per frame; "
        "any crash restarts the whole graph); per-node, each in its own. Default %(default)s",
    )
    parser.add_argument(
        "--domain-id",
        type=int,
        default=None,
        metavar="N",
        help="ROS_DOMAIN_ID of the graph (default: $ROS_DOMAIN_ID; a --bag replay without either picks "
        "a free one of its own, so two replays on one host never meet)",
    )
    parser.add_argument(
        "--frame-timeout", type=float, default=20.0, help="lockstep: seconds to wait for one frame's tracks"
    )
    parser.add_argument("--startup-timeout", type=float, default=60.0, help="seconds to wait for all nodes to come up")
    parser.add_argument(
        "--max-restarts",
        type=int,
        default=5,
        help="restarts of a node that dies or stops answering after start-up (0: stop the graph instead)",
    )
    parser.add_argument(
        "--default-malloc",
        dest="tune_malloc",
        action="store_false",
        help="start node processes with glibc's default malloc and no heap trimming instead of "
        + " ".join(f"{key}={value}" for key, value in NODE_MALLOC_SETTINGS.items()),
    )
    parser.add_argument(
        "--no-spare",
        dest="spare",
        action="store_false",
        help="restart dead nodes from scratch instead of from a warm spare process (saves its memory)",
    )
    parser.add_argument(
        "--spare-delay",
        type=float,
        default=SPARE_DELAY_S,
        metavar="S",
        help="seconds after start-up and after each restart before the warm spare starts importing "
        f"(default {SPARE_DELAY_S:g}); a node that dies sooner restarts from scratch",
    )
    parser.add_argument(
        "--executor",
        choices=EXECUTOR_CHOICES,
        default=None,
        help=f"rclpy executor of the node processes and of the player (default: ${EXECUTOR_ENV}, else events; "
        "single is rclpy's Python executors, see gldt_ros.runtime.executor; --in-process keeps a thread pool)",
    )
    args = parser.parse_args(own)
    args.ros_args = ros_args
    refused = check_ros_args(ros_args)
    if refused is not None:
        parser.error(refused)
    if args.executor is None:
        try:
            args.executor = executor_kind()
        except ValueError as error:
            parser.error(str(error))
    if args.domain_id is not None and not 0 <= args.domain_id <= MAX_DOMAIN_ID:
        parser.error(f"--domain-id must be in 0..{MAX_DOMAIN_ID}, got {args.domain_id}")
    if args.rate <= 0:
        parser.error(f"--rate must be positive, got {args.rate}")
    if not 0 <= args.spare_delay < float("inf"):
        parser.error(f"--spare-delay must be a number of seconds >= 0, got {args.spare_delay}")
    if args.bag is not None and not args.bag.exists():
        parser.error(f"--bag {args.bag}: no such file or folder")
    if args.keep_bag_stamps and args.bag is None:
        parser.error("--keep-bag-stamps needs --bag")
    args.image_transport = None  # the graph's own default (raw)
    if args.bag is not None:
        from gldt_ros.launcher.replay import bag_image_transport

        try:
            args.image_transport = bag_image_transport(args.bag)
        except (ValueError, OSError) as error:
            parser.error(f"--bag {args.bag}: {error}")
        if args.image_transport is None:
            parser.error(f"--bag {args.bag}: no sensor_msgs/Image or CompressedImage messages")
    args.params = args.params or default_params_file()
    if not args.params.is_file():
        parser.error(f"--params {args.params}: no such file")
    return args


#: Parameter overrides of a bag replay (and of any lockstep run): the player publishes reliably, so
#: the camera input takes every frame it sends (a best-effort reader may lose one).
BAG_OVERRIDES = {name: ["-p", "camera_qos:=reliable"] for name in ("frame_pair_buffer", "jptrack_tracker")}
#: Parameter overrides a lockstep replay needs besides: the scheduler waits for LOCAL reports, and the
#: buffer sends every GLOBAL pair, the global detector fuses every pair's tiles and the tracker waits
#: for every frame's detections (no planned skip, no tile pass skipped and no answer at a deadline:
#: each would depend on message timing).
LOCKSTEP_OVERRIDES = {
    "mode_scheduler": ["-p", "lockstep:=true"],
    "frame_pair_buffer": ["-p", "skip_global_when_busy:=false"],
    "global_detector": ["-p", "tile_budget:=0.0"],
    "jptrack_tracker": ["-p", "answer_deadline:=0.0"],
}


def node_ros_args(name: str, args: argparse.Namespace) -> list[str]:
    """``--ros-args`` of one node: the parameter file, the image transport of the bag replayed,
    the lockstep overrides it needs, then the user's ``--ros-args`` (last, so they win).

    In lockstep the scheduler gives up waiting for a LOCAL frame's detections when the player
    gives up waiting for its tracks (``--frame-timeout``): past that the player has moved on, and
    a scheduler still waiting (say for a local detector that was killed) would let the frames
    queue up behind it faster than it plans them.
    """
    ros_args = ["--ros-args", "--params-file", str(args.params)]
    if name == "frame_pair_buffer" and getattr(args, "image_transport", None):
        ros_args += ["-p", f"image_transport:={args.image_transport}"]
    if getattr(args, "bag", None) is not None or args.lockstep:
        ros_args += BAG_OVERRIDES.get(name, [])
    if name == "jptrack_tracker" and getattr(args, "bag", None) is not None and getattr(args, "rate", 1.0) != 1.0:
        # The player keeps the bag's intervals in the stamps: at another rate they drift from the
        # clock, so a frame's deadline counts from its arrival, not from its stamp.
        ros_args += ["-p", "answer_deadline_from:=arrival"]
    if args.lockstep:
        ros_args += LOCKSTEP_OVERRIDES.get(name, [])
        if name == "mode_scheduler":
            ros_args += ["-p", f"report_timeout:={min(max(args.frame_timeout, 0.1), 600.0)}"]
    return ros_args + list(getattr(args, "ros_args", []))


def node_arguments(name: str, args: argparse.Namespace) -> list[str]:
    """Command-line arguments of one node: :func:`node_ros_args` and the graph's namespace."""
    arguments = node_ros_args(name, args)
    if args.namespace:
        arguments += ["--ros-args", "-r", f"__ns:=/{args.namespace.strip('/')}"]
    return arguments


def process_command(group: Sequence[str], args: argparse.Namespace) -> list[str]:
    """Command line of the process of a group of nodes: a lone node's own module (what its
    ``ros2 run`` executable runs), or :mod:`gldt_ros.runtime.node_group` for several."""
    if len(group) == 1:
        return [sys.executable, "-m", NODES[group[0]], *node_arguments(group[0], args)]
    return [sys.executable, "-m", "gldt_ros.runtime.node_group", group_description(group, args)]


def group_description(group: Sequence[str], args: argparse.Namespace) -> str:
    """The JSON that names each node of ``group`` with its arguments (:mod:`gldt_ros.runtime.node_group`):
    what a group process is started with, and what turns a warm spare into it."""
    return group_json([(name, node_arguments(name, args)) for name in group])


def player_ros_args(args: argparse.Namespace) -> list[str] | None:
    """``rclpy.init`` arguments of ``pipeline``'s own process (its player and recorder, and the
    nodes ``--in-process``): the namespace and the user's ``--ros-args``, so a remapped camera
    topic is also the one the bag is played onto."""
    ros_args = ["--ros-args", "-r", f"__ns:=/{args.namespace.strip('/')}"] if args.namespace else []
    ros_args += list(getattr(args, "ros_args", []))
    return ros_args or None


#: Default seconds after start-up, and after each restart, before a spare is started: its imports
#: (rclpy, numpy, OpenCV, onnxruntime, the core) take CPU the nodes need then: a spare started
#: together with the nodes makes the global detector skip frames near the start of a 30 Hz replay
#: on a small machine. A node that dies sooner than this restarts from scratch, as without a spare.
SPARE_DELAY_S = 5.0

#: ``prctl`` option: the signal the kernel sends a process when the thread that started it ends.
PR_SET_PDEATHSIG = 1
#: What a node process gets when ``pipeline`` dies without stopping it (``kill -9``, the OOM
#: killer): SIGTERM, which rclpy turns into an orderly shutdown (DDS leaves, shared memory is
#: released) bounded by :data:`~gldt_ros.runtime.teardown_limit.TEARDOWN_LIMIT_S`.
PARENT_DEATH_SIGNAL = signal.SIGTERM


def _load_prctl() -> Callable[..., int] | None:
    try:
        import ctypes

        prctl: Callable[..., int] = ctypes.CDLL(None, use_errno=True).prctl
        return prctl
    except (OSError, AttributeError):  # not Linux
        return None


_PRCTL = _load_prctl()  # looked up here: the child between fork and exec must not import or load


def _die_with_parent(parent_pid: int) -> Callable[[], None]:
    """``preexec_fn`` of every child: the kernel sends it :data:`PARENT_DEATH_SIGNAL` when the
    thread that started it ends, and a child whose parent died before the prctl ends at once."""

    def preexec() -> None:
        if _PRCTL is not None:
            _PRCTL(PR_SET_PDEATHSIG, int(PARENT_DEATH_SIGNAL), 0, 0, 0)
        if os.getppid() != parent_pid:
            os._exit(1)

    return preexec


class _Spawner:
    """Starts every child from one long-lived thread. The parent-death signal is tied to the
    thread that forked the child, not to the process: a node restarted by the supervisor thread
    would otherwise get it when that thread ends, at every ``pipeline`` stop."""

    def __init__(self) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="gldt-spawn")

    def popen(self, command: list[str], **options: Any) -> subprocess.Popen[bytes]:
        options.update(start_new_session=True, preexec_fn=_die_with_parent(os.getpid()))

        def start() -> subprocess.Popen[bytes]:
            return subprocess.Popen(command, **options)

        return self._thread.submit(start).result()


_SPAWNER: _Spawner | None = None


def spawn(command: list[str], **options: Any) -> subprocess.Popen[bytes]:
    """``subprocess.Popen(command, **options)`` in a session of its own (Ctrl-C in a terminal
    reaches ``pipeline`` alone, which stops the nodes in order) that dies with this process."""
    global _SPAWNER
    if _SPAWNER is None:
        _SPAWNER = _Spawner()
    return _SPAWNER.popen(command, **options)


#: Seconds between killing a node that hung and starting its replacement. A process stopped mid-run
#: (SIGSTOP) and replaced at once often left the new one deaf to an input for good (the lockstep
#: replay stalled in 15 of 22 runs with a SIGSTOPped tracker); with a pause of 0.2 to 6 s between
#: kill and start, 24 of 24 went on (``docs/experiment-log.md``, 2026-12-03). A node that died by
#: itself is restarted at once.
HUNG_RESTART_PAUSE_S = 0.5


class NodeProcesses:
    """The child node processes: start, supervise (restart the ones that die or hang), stop.

    The nodes share processes as ``--processes`` says (:data:`gldt_ros.interface.graph.PROCESS_LAYOUTS`):
    :attr:`processes` maps each node to its process, the same one for the nodes of a group, and a
    group is started, killed and restarted as a whole.

    A node hangs when its heartbeat, its periodic ``/diagnostics`` status, stops (:attr:`heartbeats`,
    fed by the driver): it is killed, then restarted like a node that died.

    While supervising it keeps one warm spare (:mod:`gldt_ros.runtime.spare`, unless ``--no-spare``): an
    interpreter with the node modules imported, which becomes the first node that dies, so a
    restart skips the interpreter start and the imports.
    """

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.processes: dict[str, subprocess.Popen[bytes]] = {}
        self.restarts: dict[str, int] = {name: 0 for name in NODES}
        self.groups: tuple[tuple[str, ...], ...] = PROCESS_LAYOUTS[args.processes]
        self.supervising = False
        self.spare: subprocess.Popen[bytes] | None = None
        self._spare_due = time.monotonic() + args.spare_delay  # start-up, like a restart, goes first
        # When to look for dead segments again: a node killed within MIN_AGE_S of the last look
        # left a lock file too young for it to be told from a process that is starting up.
        self._segments_due: float | None = None
        self._lock = threading.Lock()
        #: When each node's current process last sent its status (``GraphDriver`` tells it).
        self.heartbeats = Heartbeats()
        for group in self.groups:
            self._start(group[0])

    def group_of(self, name: str) -> tuple[str, ...]:
        """The nodes that share ``name``'s process (``name`` alone in a layout of one per node)."""
        return next((group for group in self.groups if name in group), (name,))

    def _start(self, name: str) -> None:
        """Start the process of ``name``'s group, from the warm spare where one waits."""
        group = self.group_of(name)
        label = group_label(group)
        spare, self.spare = self.spare, None
        if spare is not None and spare.poll() is None and spare.stdin is not None:
            try:
                spare.stdin.write((group_description(group, self.args) + "\n").encode())
                spare.stdin.close()
                self._adopt(group, spare)
                print(f"pipeline: started {label} (pid {spare.pid}, the warm spare)", flush=True)
                return
            except OSError:
                self._discard_spare(spare)  # it died meanwhile; start from scratch
        process = spawn(
            process_command(group, self.args), env=node_environment(self.args.tune_malloc, self.args.executor)
        )
        self._adopt(group, process)
        print(f"pipeline: started {label} (pid {process.pid})", flush=True)

    def _adopt(self, group: Sequence[str], process: subprocess.Popen[bytes]) -> None:
        for name in group:
            self.processes[name] = process
            self.heartbeats.started(name, process.pid)

    def keep_spare(self) -> None:
        """Start a spare if none is waiting, a restart is still allowed, and ``--spare-delay``
        seconds have passed since start-up and since a spare was last used (or died)."""
        if not self.args.spare or not self.supervising:
            return
        if not any(count < self.args.max_restarts for count in self.restarts.values()):
            return
        if self.spare is not None and self.spare.poll() is not None:
            print(
                f"pipeline: the warm spare exited with code {self.spare.returncode}; starting another later", flush=True
            )
            self._discard_spare(self.spare)
            self.spare = None
            self._spare_due = time.monotonic() + self.args.spare_delay
        if self.spare is None and time.monotonic() >= self._spare_due:
            self.spare = spawn(
                [sys.executable, "-m", "gldt_ros.runtime.spare"],
                stdin=subprocess.PIPE,
                env=node_environment(self.args.tune_malloc, self.args.executor),
            )

    @staticmethod
    def _discard_spare(spare: subprocess.Popen[bytes]) -> None:
        """Stop a spare and release its pipe (it holds no state)."""
        if spare.stdin is not None:
            try:
                spare.stdin.close()
            except OSError:
                pass
        if spare.poll() is None:
            spare.kill()
        spare.wait()

    def dead(self) -> list[str]:
        """Nodes that are not running and will not be restarted."""
        with self._lock:
            return [
                name
                for name, process in self.processes.items()
                if process.poll() is not None
                and not (self.supervising and self.restarts[name] < self.args.max_restarts)
            ]

    def supervise(self, before_restart: Callable[[tuple[str, ...]], None] | None = None) -> list[str]:
        """Restart every node that died (once start-up is over), at most ``--max-restarts`` times each;
        a node that hangs (:meth:`_kill_silent`) is killed first, then restarted the same way.

        A node dying is a fault to survive, not a reason to stop the graph: the others keep their
        state and the restarted node rejoins through DDS discovery. ``before_restart(names)`` runs
        once per process, with all its nodes, before the new process starts (the driver notes which
        endpoints were the dead one's, and relinks the whole group at once), and outside this
        object's lock, which the driver's own waits take.
        """
        self._clean_segments_if_due()
        with self._lock:
            if not self.supervising:
                return []
            hung = self._kill_silent()
            dying = [  # the groups whose process ended
                group
                for group in self.groups
                if self.processes[group[0]].poll() is not None and self.restarts[group[0]] < self.args.max_restarts
            ]
        if any(name in hung for group in dying for name in group):
            time.sleep(HUNG_RESTART_PAUSE_S)
        for group in dying:
            if before_restart is not None:
                try:
                    before_restart(tuple(group))
                except Exception as error:  # noqa: BLE001 - the supervisor must outlive a failed notice
                    print(f"pipeline: noting the restart of {group_label(group)} failed: {error}", flush=True)
        restarted: list[str] = []
        with self._lock:
            if not self.supervising:
                return restarted
            for group in dying:
                for name in group:
                    self.restarts[name] += 1
                code = self.processes[group[0]].returncode
                attempt = f"{self.restarts[group[0]]}/{self.args.max_restarts}"
                if group[0] not in hung:  # a hung node was announced when killed
                    print(
                        f"pipeline: node {group_label(group)} exited with code {code}; restarting ({attempt})",
                        flush=True,
                    )
                self._start(group[0])
                self._spare_due = time.monotonic() + self.args.spare_delay
                restarted.extend(group)
            self.keep_spare()
        if restarted:
            report_removed_segments()
            self._segments_due = time.monotonic() + MIN_AGE_S
        return restarted

    def _kill_silent(self) -> set[str]:
        """SIGKILL every running node whose heartbeat stopped (a stopped process ignores SIGTERM
        until continued), so that it is restarted like one that died, and say so; return them. One
        with no restart left is killed too, and is dead for good (:meth:`dead`)."""
        hung: set[str] = set()
        for name, silent_s in self.heartbeats.silent().items():
            process = self.processes[name]
            if name in hung:
                continue  # its group's process was killed for another of its nodes
            if process.poll() is not None:
                continue  # it died: restarted as such
            if self.restarts[name] < self.args.max_restarts:
                then = f"killing and restarting ({self.restarts[name] + 1}/{self.args.max_restarts})"
            else:
                then = "killing it, no restart left"
            print(f"pipeline: node {name} sent no heartbeat for {silent_s:.1f} s; {then}", flush=True)
            process.kill()
            try:
                process.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                print(f"pipeline: node {name} survived SIGKILL for 2 s", flush=True)
                continue
            hung.update(self.group_of(name))
        return hung

    def _clean_segments_if_due(self) -> None:
        """Look again for segments of nodes that died, once their lock files are old enough to be
        judged (:data:`~gldt_ros.runtime.shm_cleanup.MIN_AGE_S` after the last restart)."""
        due = self._segments_due
        if due is None or time.monotonic() < due:
            return
        self._segments_due = None
        report_removed_segments()

    def stop(self, grace_s: float = 10.0) -> int:
        """SIGINT every child, escalate to SIGTERM/SIGKILL; return the number that did not exit cleanly."""
        with self._lock:
            self.supervising = False
            spare, self.spare = self.spare, None
        if spare is not None:
            self._discard_spare(spare)
        started = [
            (group_label(group), self.processes[group[0]]) for group in self.groups if group[0] in self.processes
        ]
        for _, process in started:
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        deadline = time.monotonic() + grace_s
        unclean = 0
        for name, process in started:
            try:
                code = process.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                print(
                    f"pipeline: node {name} did not stop within {grace_s:g} s of SIGINT; "
                    "its threads' stacks follow, then SIGTERM",
                    flush=True,
                )
                process.send_signal(STACK_DUMP_SIGNAL)
                time.sleep(0.5)  # faulthandler writes from its signal handler; let it finish
                process.terminate()
                try:
                    code = process.wait(timeout=3.0)
                except subprocess.TimeoutExpired:
                    process.kill()
                    code = process.wait()
            if code == TEARDOWN_TIMEOUT_EXIT:
                # Stopped serving, then stuck in rclpy's destroy_node; it ended itself (its stacks are above).
                print(
                    f"pipeline: node {name} stopped, but its rclpy teardown hung "
                    f"and it exited after {TEARDOWN_LIMIT_S} s",
                    flush=True,
                )
            elif code not in (0, -signal.SIGINT, 130):
                print(f"pipeline: node {name} exited with code {code}", flush=True)
                unclean += 1
        due = self._segments_due
        if due is not None:  # a node died shortly before: let its lock file age enough to be judged
            time.sleep(max(0.0, min(due - time.monotonic(), MIN_AGE_S)))
        report_removed_segments()
        return unclean


def report_removed_segments() -> None:
    """Remove the shared-memory segments of dead DDS processes (:mod:`gldt_ros.runtime.shm_cleanup`: a
    killed node cannot remove its own) and say how many, if any."""
    removed = remove_dead_segments()
    if removed:
        print(
            f"pipeline: removed {len(removed)} stale shared-memory segment(s) from /dev/shm, left by DDS processes "
            "no longer running (an earlier run's, or a restarted node's); harmless",
            flush=True,
        )


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``ros2 run gldt_ros pipeline``."""
    args = parse_args(argv if argv is not None else sys.argv[1:])
    domain = choose_domain(args)
    if domain is not None:
        print(domain, flush=True)
    import rclpy

    from gldt_ros.launcher.replay import LOST_FRAMES_EXIT, GraphDriver

    use_graph_dds_profile()
    use_frames_profile_if_shipped()  # this process plays the camera (and hosts the buffer --in-process)
    from rclpy.signals import SignalHandlerOptions

    # Ctrl-C (SIGINT) is Python's KeyboardInterrupt here, handled below like any stop: rclpy's own
    # handler would shut the context down under the player, whose next publish then fails. Set
    # explicitly: started as a script's background job (`pipeline ... &`), the process inherits
    # SIGINT ignored and Python then installs no handler, so `kill -INT` would not stop it.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    rclpy.init(args=player_ros_args(args), signal_handler_options=SignalHandlerOptions.NO)
    if args.image_transport is not None:
        print(f"pipeline: the bag's frames go to image_transport {args.image_transport}", flush=True)
    stop_requested = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop_requested.set())
    children: NodeProcesses | None = None
    in_process_nodes: list[Any] = []
    # --in-process: the graph's nodes share this process's executor, the events executor unless
    # --executor single. rclpy's thread pool makes a lockstep replay crawl there: with a node's
    # callback running, its other subscriptions stay ready, and the pool's wait loop spins on them
    # holding the GIL the running callback needs.
    executor, spin = background_executor(args.executor)
    driver = GraphDriver(args)
    executor.add_node(driver)
    spin_thread = threading.Thread(target=spin, name="gldt-spin", daemon=True)
    status = 0
    started = time.monotonic()
    try:
        if args.in_process:
            if args.tune_malloc:
                start_heap_trimming(DEFAULT_PERIOD_S)  # the nodes' frames now churn this process's heap
            in_process_nodes = _create_in_process_nodes(args)
            for node in in_process_nodes:
                executor.add_node(node)
        else:
            children = NodeProcesses(args)
            driver.heartbeats = children.heartbeats
        spin_thread.start()
        expected = [f"{args.namespace.strip('/')}/{n}".strip("/") for n in NODES]
        if not driver.wait_for_nodes(expected, args.startup_timeout, lambda: children.dead() if children else []):
            return 1
        placed = "all in this process" if args.in_process else f"processes {args.processes}"
        spun_by = f"the {args.executor} executor, {placed}"
        print(f"pipeline: {len(NODES)} nodes up in {time.monotonic() - started:.1f} s ({spun_by})", flush=True)
        if children is not None:
            children.supervising = True
            supervisor = threading.Thread(
                target=_supervise_until, args=(children, stop_requested, driver.note_restarted), daemon=True
            )
            supervisor.start()
        if args.bag is not None:
            summary = driver.replay(stop_requested, lambda: children.dead() if children else [])
            print(summary, flush=True)
            if driver.loss is not None and not stop_requested.is_set():
                print(f"pipeline: frames lost or unanswered: {driver.loss} (exit {LOST_FRAMES_EXIT})", flush=True)
                status = LOST_FRAMES_EXIT
        else:
            while not stop_requested.is_set():
                dead = children.dead() if children else []
                if dead:
                    print(f"pipeline: node(s) {', '.join(dead)} exited; stopping", flush=True)
                    status = 1
                    break
                stop_requested.wait(0.2)
    except KeyboardInterrupt:
        print("pipeline: interrupted, stopping", flush=True)
    finally:
        stop_requested.set()
        driver.close()
        if children is not None and children.stop():
            status = status or 1
        executor.shutdown(timeout_sec=2.0)
        if spin_thread.is_alive():
            spin_thread.join(timeout=2.0)
        for node in in_process_nodes:
            node.destroy_node()
        driver.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return status


def _supervise_until(
    children: NodeProcesses,
    stop: threading.Event,
    on_restart: Callable[[tuple[str, ...]], None] | None = None,
    period_s: float = 0.2,
) -> None:
    """Restart dead nodes until asked to stop (each node prints "ready" once it is back up),
    telling ``on_restart`` which before each starts (the driver relinks the graph before its next
    lockstep frame)."""
    while not stop.wait(period_s):
        children.supervise(on_restart)


def _create_in_process_nodes(args: argparse.Namespace) -> list[Any]:
    """Instantiate every node in this process with the parameter file applied."""
    import importlib

    return [
        importlib.import_module(module).create_node(cli_args=node_ros_args(name, args))
        for name, module in NODES.items()
    ]


if __name__ == "__main__":
    sys.exit(main())
