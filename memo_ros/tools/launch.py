"""Start the graph for a studio: one contour_node per camera, each its own process.

Every node gets the studio file as ``--ros-args --params-file``; its output is
prefixed with its name.  The launcher supervises, like launch's ``respawn``: a
node that ends is said so and started again after a backoff (0.5 s, doubling
to 5 s), its restarts counted (``MEMO_ROS_RESTARTS`` in its environment, which
its /diagnostics reports as ``restarts``).  A node that keeps dying (more than
``--max-restarts`` deaths within ``--restart-window`` seconds) stops the graph
with one line saying why, and a non-zero exit; Ctrl-C (or SIGTERM) stops them
all and exits 0.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time

from memo_ros.core.formats.studio import Studio, studio_path

STOP_GRACE_S = 5.0
RESPAWN_DELAY_S = 0.5  # first restart after this long, doubling up to RESPAWN_DELAY_MAX_S
RESPAWN_DELAY_MAX_S = 5.0
MAX_RESTARTS = 5  # deaths of one node within RESTART_WINDOW_S that stop the graph
RESTART_WINDOW_S = 60.0
RESTARTS_ENV = 'MEMO_ROS_RESTARTS'  # how often the launcher restarted this node (its /diagnostics)
ROLES = ('all', 'cameras', 'tracking')
REPLAY_IMAGE_QUEUE = 100  # image queue of the contour nodes when a bag is replayed into them
REPLAY_ROI_WAIT = (
    0.5  # s a contour node waits for the tracked body of the previous image in a replay
)
REPLAY_MAX_LAG = 3600.0  # s: a replay tracks every frame, however far behind it falls
REPLAY_WINDOW_MARGIN = 0  # a replay segments whole frames: the contour window is a live measure
REPLAY_JOIN_TIMEOUT = (
    3.0  # s the tracker waits for a frame's contours in a replay (a loaded host is slow,
)
# and with back-pressure the player waits anyway)
# replay: reliable images, and a burst of images re-sent to a late-matching reader must not
# overflow its queue
REPLAY_CONTOUR_PARAMS = {
    'reliable_images': True,
    'image_queue_depth': REPLAY_IMAGE_QUEUE,
    'roi_wait': REPLAY_ROI_WAIT,
    'window_margin': REPLAY_WINDOW_MARGIN,
}
REPLAY_TRACKER_PARAMS = {
    'join_timeout': REPLAY_JOIN_TIMEOUT,
    'max_lag': REPLAY_MAX_LAG,
    # each frame tracked the same way however far behind: every iteration (iterations_behind at
    # its top, never below iterations) and every search when due, so a slow machine makes a
    # replay slower, not different
    'iterations_behind': 20,
    'defer_searches': False,
    'latency_target': 0.0,  # and no frame shed under load
}


@dataclass
class NodeProcess:
    """A launched node: its label, command and process."""

    label: str
    command: list[str]
    process: subprocess.Popen | None = None
    restarts: int = 0
    deaths: list[float] = field(default_factory=list)  # monotonic times of its recent deaths
    respawn_at: float | None = None  # when a dead node is started again


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this command's arguments and options."""
    parser.add_argument(
        'studio', help='studio YAML (path, or a shipped name such as studio_orthogonal)'
    )
    parser.add_argument(
        '--reliable-images',
        action='store_true',
        help='for bag replay: subscribe images reliably with a 100-image queue instead of best '
        "effort, and let the tracker wait up to 3 s for a frame's contours",
    )
    parser.add_argument(
        '--role',
        default='all',
        choices=ROLES,
        help='what this host runs: all (default); cameras: the contour nodes (a camera host); '
        'tracking: the selector and tracker or the walker (the tracking host)',
    )
    parser.add_argument(
        '--log-level', default='info', choices=('debug', 'info', 'warn', 'error', 'fatal')
    )
    parser.add_argument(
        '--max-restarts',
        type=int,
        default=MAX_RESTARTS,
        help=f'a node that dies more often than this within --restart-window stops the graph '
        f'(default {MAX_RESTARTS}; 0: the first death stops it, as without supervision)',
    )
    parser.add_argument(
        '--restart-window',
        type=float,
        default=RESTART_WINDOW_S,
        help=f'seconds over which deaths are counted (default {RESTART_WINDOW_S:g})',
    )


def run(args: argparse.Namespace) -> int:
    """Run the command with parsed ``args``; return its exit code."""
    path = studio_path(args.studio).resolve()
    studio = Studio.load(path)
    nodes = graph_commands(studio, path, args.reliable_images, args.log_level, args.role)
    if args.max_restarts < 0 or not args.restart_window > 0:
        from memo_ros.tools.cli import CliError

        raise CliError('--max-restarts must be >= 0 and --restart-window > 0')
    return Launcher(nodes, args.max_restarts, args.restart_window).run()


def parameter_arguments(params: dict[str, bool | int | float]) -> list[str]:
    """Return ``-p name:=value`` node arguments for ``params`` (booleans as ROS spells them)."""
    return [a for name, value in params.items() for a in ('-p', f'{name}:={str(value).lower()}')]


def graph_commands(
    studio: Studio,
    path: Path,
    reliable_images: bool = False,
    log_level: str = 'info',
    role: str = 'all',
) -> list[NodeProcess]:
    """Return the processes of the graph.

    One contour_node per camera, in its camera's namespace, and the articulated tracker with its
    camera selector for a multi-camera studio (or one whose file configures ``tracker_node``);
    ``role`` cameras keeps the contour nodes only, tracking the others.
    """
    if role not in ROLES:
        raise ValueError(f'unknown role {role!r}; one of {", ".join(ROLES)}')
    nodes = []
    for cam in studio.camera_names if role in ('all', 'cameras') else []:
        command = [
            sys.executable,
            '-m',
            'memo_ros.nodes.contour_node',
            '--ros-args',
            '-r',
            f'__ns:=/{cam}',
            '--params-file',
            str(path),
            '--log-level',
            log_level,
        ]
        if reliable_images:
            command += parameter_arguments(REPLAY_CONTOUR_PARAMS)
        nodes.append(NodeProcess(f'{cam}/contour_node', command))
    if role == 'cameras':
        return nodes
    if len(studio.camera_names) > 1 or 'tracker_node' in studio.node_parameters:
        nodes.append(
            NodeProcess(
                'selector_node',
                [
                    sys.executable,
                    '-m',
                    'memo_ros.nodes.selector_node',
                    '--ros-args',
                    '--params-file',
                    str(path),
                    '--log-level',
                    log_level,
                ],
            )
        )
        tracker = [
            sys.executable,
            '-m',
            'memo_ros.nodes.tracker_node',
            '--ros-args',
            '--params-file',
            str(path),
            '--log-level',
            log_level,
        ]
        if reliable_images:
            tracker += parameter_arguments(REPLAY_TRACKER_PARAMS)
        nodes.append(NodeProcess('tracker_node', tracker))
    if (
        'walker_node' in studio.node_parameters
    ):  # Rohr's walking tracker: the studio file configures it
        nodes.append(
            NodeProcess(
                'walker_node',
                [
                    sys.executable,
                    '-m',
                    'memo_ros.nodes.walker_node',
                    '--ros-args',
                    '--params-file',
                    str(path),
                    '--log-level',
                    log_level,
                ],
            )
        )
    return nodes


class Launcher:
    """Runs node processes, prefixes their output, and stops them all together."""

    def __init__(
        self,
        nodes: list[NodeProcess],
        max_restarts: int = MAX_RESTARTS,
        restart_window: float = RESTART_WINDOW_S,
    ) -> None:
        self.nodes = nodes
        self.max_restarts = max_restarts
        self.restart_window = restart_window
        self._stop = threading.Event()

    def run(self) -> int:
        """Start every node, supervise them until a stop, stop them all; the exit code."""
        previous = {
            s: signal.signal(s, lambda *_: self._stop.set())
            for s in (signal.SIGINT, signal.SIGTERM)
        }
        try:
            for node in self.nodes:
                self._start(node)
            return self._supervise()
        finally:
            self._stop_all()
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    def _start(self, node: NodeProcess) -> None:
        """Start (or restart) one node, its restart count in its environment."""
        env = dict(os.environ, **{RESTARTS_ENV: str(node.restarts)})
        node.process = subprocess.Popen(
            node.command,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
            start_new_session=True,
            env=env,
        )
        node.respawn_at = None
        threading.Thread(target=self._relay, args=(node,), daemon=True).start()
        again = f', restart {node.restarts}' if node.restarts else ''
        self._say(f'started {node.label} (pid {node.process.pid}{again})')

    def _supervise(self) -> int:
        """Restart nodes that die, with a backoff; stop everything when one keeps dying."""
        while not self._stop.is_set():
            now = time.monotonic()
            for node in self.nodes:
                if node.respawn_at is not None:
                    if now >= node.respawn_at:
                        node.restarts += 1
                        self._start(node)
                    continue
                code = node.process.poll() if node.process is not None else None
                if code is None:
                    continue
                node.deaths = [t for t in node.deaths if now - t < self.restart_window] + [now]
                if len(node.deaths) > self.max_restarts:
                    self._say(
                        f'{node.label} {exit_reason(code)}; it died {len(node.deaths)} times in '
                        f'{self.restart_window:g} s, more than --max-restarts '
                        f'{self.max_restarts}: stopping the others'
                    )
                    return code if code > 0 else 1
                delay = min(RESPAWN_DELAY_S * 2 ** (len(node.deaths) - 1), RESPAWN_DELAY_MAX_S)
                node.respawn_at = now + delay
                self._say(f'{node.label} {exit_reason(code)}; restarting it in {delay:g} s')
            time.sleep(0.05)
        self._say('stopping on request')
        return 0

    def _stop_all(self) -> None:
        running = [n for n in self.nodes if n.process is not None and n.process.poll() is None]
        for node in running:
            node.process.send_signal(signal.SIGINT)
        deadline = time.monotonic() + STOP_GRACE_S
        for node in running:
            try:
                node.process.wait(max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                node.process.kill()
                node.process.wait()
                self._say(f'{node.label} did not stop within {STOP_GRACE_S:.0f} s: killed')

    def _relay(self, node: NodeProcess) -> None:
        for line in node.process.stdout:
            sys.stdout.write(f'[{node.label}] {line}')
            sys.stdout.flush()

    @staticmethod
    def _say(text: str) -> None:
        print(f'[launch] {text}', flush=True)


def exit_reason(code: int) -> str:
    """How a process ended, in words."""
    if code < 0:
        try:
            return f'was killed by {signal.Signals(-code).name}'
        except ValueError:
            return f'was killed by signal {-code}'
    return f'exited with code {code}'
