"""
Benchmark: wall time from starting a freshly `colcon build`-installed sim_node to its first state.

    .venv/bin/python -m benchmarks.performance.bench_first_state [--scenes pump_cycle shell_robot]
                                                     [--repeats 3] [--keep WORKDIR]

Copies the repository into a temporary colcon workspace (as test/test_colcon_build.py does) and
builds it twice with the venv's colcon:
  - cold:   PULSEJET_SKIP_NUMBA_WARMUP=1, i.e. the install as it was before setup.py warmed numba's
            cache (no cache files in the installed tree); before each start the installed tree's
            numba cache files are deleted, so every start is a fresh install's first start;
  - warmed: a plain `colcon build` (setup.py compiles the shipped scenes' kernels into the
            installed tree's numba cache).
For each scene it starts the installed console script
install/pulsejet_sim/lib/pulsejet_sim/sim_node with the environment of `. install/setup.sh` (what
`ros2 run` does), without the rclpy wheels' bootstrap guard so the interpreter re-executes itself
at start-up as it does for a user, in an isolated DDS domain
(ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST), and measures from Popen to
  - the node's first output line (its first log line), and
  - the first /clock message received by a subscriber in this process (the first published state).
Writes benchmarks/results/first_state.md (date, machine, command, table). Not a test.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
from pathlib import Path
import platform
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time

from pulsejet_sim.ros.launching import default_domain_id, isolated_environment

REPO = Path(__file__).resolve().parents[2]
PACKAGE = 'pulsejet_sim'
RESULTS = REPO / 'benchmarks' / 'results' / 'first_state.md'
EXCLUDE = (
    '.venv',
    'venv',
    'build',
    'install',
    'log',
    'runs',
    '.git',
    '__pycache__',
    '*.egg-info',
    '.pytest_cache',
    '*.mcap',
    '*.png',
)
BOOTSTRAP_GUARD = '_ROS_WHEELS_BOOTSTRAP_COMPLETE'
TIMEOUT_S = 300.0


def base_env() -> dict:
    env = dict(os.environ)
    for key in ('PYTHONPATH', 'AMENT_PREFIX_PATH', 'COLCON_PREFIX_PATH', 'NUMBA_CACHE_DIR'):
        env.pop(key, None)
    return env


def colcon_build(ws: Path, warm: bool) -> tuple[float, str]:
    """
    Build a fresh workspace: copy the repository, colcon build.

    Returns (seconds, the warm-up log line).
    """
    shutil.copytree(REPO, ws / 'src' / PACKAGE, ignore=shutil.ignore_patterns(*EXCLUDE))
    env = base_env()
    if warm:
        env.pop('PULSEJET_SKIP_NUMBA_WARMUP', None)
    else:
        env['PULSEJET_SKIP_NUMBA_WARMUP'] = '1'
    exe = Path(sys.executable).parent / 'colcon'
    cmd = ([str(exe)] if exe.exists() else [sys.executable, '-m', 'colcon']) + [
        'build',
        '--event-handlers',
        'console_direct+',
    ]
    t0 = time.monotonic()
    proc = subprocess.run(cmd, cwd=ws, env=env, capture_output=True, text=True, timeout=3600)
    seconds = time.monotonic() - t0
    if proc.returncode:
        sys.exit(f'colcon build failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}')
    line = next(
        (ln for ln in (proc.stdout + proc.stderr).splitlines() if 'numba compile cache' in ln), ''
    )
    return seconds, line.strip()


def sourced_env(ws: Path, domain: int) -> dict:
    """
    Return the environment after `. install/setup.sh`.

    As a user's shell has it before `ros2 run`.
    """
    out = subprocess.run(
        ['sh', '-c', f'. "{ws}/install/setup.sh" && env -0'],
        env=base_env(),
        capture_output=True,
        check=True,
    ).stdout.decode()
    env = dict(item.split('=', 1) for item in out.split('\0') if '=' in item)
    env.pop(BOOTSTRAP_GUARD, None)  # the console script re-executes itself like a user's would
    return isolated_environment(domain, base=env)


def installed_cache_files(ws: Path) -> list[Path]:
    return [p for p in (ws / 'install' / PACKAGE).rglob('*') if p.suffix in ('.nbi', '.nbc')]


class ClockWatch:
    """
    A /clock subscriber in this process.

    first_at holds the monotonic time of the first message.
    """

    def __init__(self, domain: int):
        from pulsejet_sim.ros.executor import make_executor
        import rclpy
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock

        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(
            context=self.context,
            domain_id=domain,
            signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
        )
        self.node = rclpy.create_node('bench_first_state', context=self.context)
        self.first_at = None
        self.node.create_subscription(
            Clock,
            '/clock',
            self._on_clock,
            QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT),
        )
        self.executor = make_executor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _on_clock(self, msg):
        if self.first_at is None:
            self.first_at = time.monotonic()

    def _spin(self):
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.01)

    def close(self):
        self._stop.set()
        self.thread.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.context)


def cpu_seconds(pid: int) -> float:
    """
    User + system CPU seconds of a process so far.

    From Linux /proc; the rclpy wheels' re-exec keeps the pid.
    """
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, IndexError, ValueError):
        return float('nan')


def first_state(ws: Path, scene: str, domain: int) -> tuple[float, float, float]:
    """
    Time one start of the installed sim_node to its first output and first /clock.

    (seconds to the first output line, seconds to the first /clock, CPU seconds the node used up to
    the first /clock) of one start of the installed sim_node.
    """
    env = sourced_env(ws, domain)
    exe = ws / 'install' / PACKAGE / 'lib' / PACKAGE / 'sim_node'
    watch = ClockWatch(domain)
    first_line = [None]
    try:
        time.sleep(0.5)  # the subscriber is up before the node starts
        t0 = time.monotonic()
        proc = subprocess.Popen(
            [str(exe), '--ros-args', '-p', f'scene:={scene}'],
            env=env,
            cwd=ws,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )

        def read():
            for line in proc.stdout:
                if first_line[0] is None and line.strip():
                    first_line[0] = time.monotonic()

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        try:
            while (
                watch.first_at is None
                and proc.poll() is None
                and time.monotonic() - t0 < TIMEOUT_S
            ):
                time.sleep(0.005)
            if watch.first_at is None:
                raise RuntimeError(
                    f'no /clock from sim_node (scene {scene}) within {TIMEOUT_S:.0f} s '
                    f'(exit status {proc.poll()})'
                )
            cpu = cpu_seconds(proc.pid)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGINT)
                try:
                    proc.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
            reader.join(timeout=5)
        line_s = (first_line[0] - t0) if first_line[0] is not None else float('nan')
        return line_s, watch.first_at - t0, cpu
    finally:
        watch.close()


def machine() -> str:
    cpu = platform.processor() or '?'
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                cpu = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    import numba

    return (
        f'{platform.node()}: {cpu}, {os.cpu_count()} cores (nproc), load average'
        f' {", ".join(f"{x:.2f}" for x in os.getloadavg())} at start; Python'
        f' {platform.python_version()}, numba {numba.__version__}, {platform.system()}'
        f' {platform.release()}'
    )


def fmt(values: list[float]) -> str:
    if len(values) == 1:
        return f'{values[0]:.2f}'
    return f'{statistics.median(values):.2f} ({min(values):.2f}-{max(values):.2f})'


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--scenes', nargs='+', default=['pump_cycle', 'shell_robot'])
    parser.add_argument(
        '--repeats', type=int, default=3, help='starts per scene with the warmed cache'
    )
    parser.add_argument(
        '--cold-repeats', type=int, default=1, help='starts per scene with an empty cache'
    )
    parser.add_argument('--keep', help='build the workspaces under this directory and keep them')
    parser.add_argument(
        '--no-write', action='store_true', help=f'do not write {RESULTS.relative_to(REPO)}'
    )
    args = parser.parse_args(argv)

    domain = default_domain_id()  # 215-232: isolated from the tests' 1-100
    started = _dt.datetime.now().astimezone()
    host = machine()
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix='bench_first_state_'))
    root.mkdir(parents=True, exist_ok=True)
    rows = []
    try:
        ws_cold, ws_warm = root / 'ws_cold', root / 'ws_warm'
        for ws in (ws_cold, ws_warm):
            if ws.exists():
                shutil.rmtree(ws)
        print('colcon build (warm-up skipped: the install before this change) ...', flush=True)
        build_cold_s, _ = colcon_build(ws_cold, warm=False)
        print(f'  {build_cold_s:.1f} s', flush=True)
        print('colcon build (numba cache warmed at install) ...', flush=True)
        build_warm_s, warm_line = colcon_build(ws_warm, warm=True)
        print(f'  {build_warm_s:.1f} s: {warm_line}', flush=True)
        n_cache = len(installed_cache_files(ws_warm))
        for scene in args.scenes:
            cold, warm = [], []
            for _ in range(args.cold_repeats):
                for path in installed_cache_files(ws_cold):
                    path.unlink()
                cold.append(first_state(ws_cold, scene, domain))
                print(
                    f'  {scene} cold:   first line {cold[-1][0]:.2f} s, first /clock'
                    f' {cold[-1][1]:.2f} s, CPU {cold[-1][2]:.2f} s',
                    flush=True,
                )
            for _ in range(args.repeats):
                warm.append(first_state(ws_warm, scene, domain))
                print(
                    f'  {scene} warmed: first line {warm[-1][0]:.2f} s, first /clock'
                    f' {warm[-1][1]:.2f} s, CPU {warm[-1][2]:.2f} s',
                    flush=True,
                )
            rows.append((scene, cold, warm))
    finally:
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)

    cli = argv if argv is not None else sys.argv[1:]
    module = 'benchmarks.performance.bench_first_state'
    command = ' '.join(['.venv/bin/python', '-m', module, *cli])
    lines = [
        (
            '# First state of a freshly installed sim_node: cold compile vs numba cache warmed at'
            ' install'
        ),
        '',
        f'- date: {started:%Y-%m-%d %H:%M %Z}',
        f'- machine: {host}',
        f'- command: `{command}`',
        (
            '- builds (fresh workspace each, `colcon build`): cold (PULSEJET_SKIP_NUMBA_WARMUP=1,'
            f' as before the warm-up) {build_cold_s:.1f} s; warmed {build_warm_s:.1f} s, {n_cache}'
            f' numba cache files in the installed tree; setup.py: `{warm_line}`'
        ),
        (
            '- measured: Popen of install/pulsejet_sim/lib/pulsejet_sim/sim_node (env of `.'
            " install/setup.sh`, the rclpy wheels' interpreter re-exec included, default"
            ' parameters but `scene`) to its first output line and to the first /clock received'
            ' by a subscriber already running in an isolated DDS domain; cold = the installed'
            " tree's numba cache files deleted before each start (a fresh install's first"
            f' start); seconds, median (min-max) over {args.repeats} warmed starts,'
            f' {args.cold_repeats} cold. The CPU column (user+system seconds of the node process'
            ' up to its first state) does not depend on what else the shared machine runs; the'
            ' wall times do (see the load average)'
        ),
        '',
        (
            '| scene | model | cold compile: first log line (s) | cold compile: first state (s) '
            '| cold compile: CPU to first state (s) | warmed cache: first log line (s) '
            '| warmed cache: first state (s) | warmed cache: CPU to first state (s) |'
        ),
        '|---|---|---|---|---|---|---|---|',
    ]
    from pulsejet_sim.scene import load_scene_data

    for scene, cold, warm in rows:
        model = load_scene_data(scene)[0].get('model', '?')
        lines.append(
            f'| {scene} | {model} | '
            + ' | '.join(fmt([r[i] for r in cold]) for i in range(3))
            + ' | '
            + ' | '.join(fmt([r[i] for r in warm]) for i in range(3))
            + ' |'
        )
    text = '\n'.join(lines) + '\n'
    print(text)
    if not args.no_write:
        RESULTS.parent.mkdir(parents=True, exist_ok=True)
        RESULTS.write_text(text)
        print(f'written to {RESULTS.relative_to(REPO)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
