r"""
`make demo`: sim_node + controller_node as processes, every topic recorded to MCAP, then a summary.

    python -m pulsejet_sim.ros.demo [--scene shell_robot] [--duration 10] [--real-time-factor 1] \
        [--out FILE]

The nodes run in their own ROS domain (ROS_DOMAIN_ID from the environment if set, otherwise one
derived from this process id) with localhost-only discovery. The recording is written to
`runs/demo-<timestamp>.mcap` (or --out); the plot is written next to it.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from pulsejet_sim.core.topics import TOPIC_CLOCK
from pulsejet_sim.ros.launching import pick_domain_id
from pulsejet_sim.ros.node_params import node_command
from pulsejet_sim.scene import DEFAULT_SCENE

# sim_node is judged by progress, not by a wall-clock total that a loaded machine can exceed:
# its first /clock may take this long (scene loading and JIT compilation of a cold cache, measured
# 41 s on a fresh clone with both cores busy), after that simulated time must not stand still
# for STALL_TIMEOUT_S
STARTUP_TIMEOUT_S = 180.0
STALL_TIMEOUT_S = 30.0
STOP_TIMEOUT_S = 10.0


class DemoError(RuntimeError):
    pass


def demo_environment(env=None) -> dict:
    """Copy of the environment with an isolated domain and localhost discovery."""
    env = dict(os.environ if env is None else env)
    if not env.get('ROS_DOMAIN_ID'):
        env['ROS_DOMAIN_ID'] = str(pick_domain_id())
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    env.setdefault('RCUTILS_COLORIZED_OUTPUT', '0')
    env['RCUTILS_LOGGING_BUFFERED_STREAM'] = '0'
    env['PYTHONUNBUFFERED'] = '1'
    return env


def stop_process(proc: subprocess.Popen, timeout_s: float = STOP_TIMEOUT_S) -> int:
    """SIGINT, wait, then SIGKILL. Returns the exit code."""
    if proc.poll() is None:
        try:
            proc.send_signal(signal.SIGINT)
            return proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            return proc.wait(timeout=timeout_s)
    return proc.returncode


def tail(path: Path, lines: int = 25) -> str:
    try:
        text = path.read_text(errors='replace').splitlines()
    except OSError:
        return ''
    return '\n'.join('    ' + line for line in text[-lines:])


def make_recorder(node, path: Path):
    """
    Return an in-process recorder of every pulsejet topic and of /diagnostics.

    The pulsejet topics include the commands, the ledger and /clock; /diagnostics carries the
    node's health: achieved real-time factor, dropped time, watchdog, faults.
    """
    from pulsejet_sim.ros import messages
    from pulsejet_sim.ros.recorder import Recorder

    return Recorder(
        node,
        str(path),
        list(messages.TOPIC_TYPES)
        + [f'{messages.TOPIC_DIAGNOSTICS}:diagnostic_msgs/msg/DiagnosticArray'],
    )


def run_demo(
    scene: str,
    duration_s: float,
    real_time_factor: float,
    out: Path,
    publish_rate_hz: float = 0.0,
    quiet: bool = False,
) -> dict:
    """Run the demo; returns {'mcap': Path, 'codes': {...}, 'messages': int}. Raises DemoError."""
    from pulsejet_sim.ros.executor import make_executor
    import rclpy

    if duration_s <= 0:
        raise DemoError(f'--duration={duration_s!r}; allowed: > 0 s of simulated time')
    if real_time_factor <= 0:
        raise DemoError(f'--real-time-factor={real_time_factor!r}; allowed: > 0')
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    env = demo_environment()
    domain_id = int(env['ROS_DOMAIN_ID'])
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = env['ROS_AUTOMATIC_DISCOVERY_RANGE']
    log = (lambda *a: None) if quiet else (lambda *a: print(*a, flush=True))
    log(
        f'pulsejet demo: scene {scene!r}, {duration_s:g} s simulated at real-time factor '
        f'{real_time_factor:g}, ROS_DOMAIN_ID={domain_id}, '
        f'discovery {env["ROS_AUTOMATIC_DISCOVERY_RANGE"]}'
    )

    stem = out.with_suffix('') if out.suffix == '.mcap' else out
    logs = {
        'controller_node': Path(f'{stem}.controller_node.log'),
        'sim_node': Path(f'{stem}.sim_node.log'),
    }
    sim_params = {
        'scene': scene,
        'duration_s': float(duration_s),
        'real_time_factor': float(real_time_factor),
        'wait_for_subscribers': 2,
        'wait_timeout_s': 30.0,
    }
    if publish_rate_hz > 0:
        sim_params['publish_rate_hz'] = float(publish_rate_hz)
    commands = {
        'controller_node': node_command('pulsejet_ctrl.controller_node', {'scene': scene}),
        'sim_node': node_command('pulsejet_sim.ros.sim_node', sim_params),
    }

    # Ctrl-C reaches the whole process group: note it here (the handler runs before the next
    # poll of the children), so that children stopping on the same signal are not reported as
    # failures
    stop_requested = {'signal': None}

    def on_signal(signum, _frame):
        stop_requested['signal'] = signum

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}

    context = rclpy.Context()
    rclpy.init(
        context=context,
        domain_id=domain_id,
        signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
    )
    procs: dict[str, subprocess.Popen] = {}
    files = []
    recorder = None
    node = None
    codes = {}
    interrupted = False
    try:
        node = rclpy.create_node('pulsejet_demo_recorder', context=context)
        executor = make_executor(context=context)
        executor.add_node(node)
        recorder = make_recorder(node, out)
        for name, cmd in commands.items():
            f = open(logs[name], 'wb')
            files.append(f)
            procs[name] = subprocess.Popen(
                cmd, env=env, stdout=f, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
            )
        log(
            f'started controller_node (pid {procs["controller_node"].pid}) and sim_node '
            f'(pid {procs["sim_node"].pid}); logs in {logs["sim_node"].parent}/'
        )
        sim = procs['sim_node']
        clock_topic = node.resolve_topic_name(TOPIC_CLOCK)
        ticks, last_progress = 0, time.monotonic()
        try:
            while sim.poll() is None:
                executor.spin_once(timeout_sec=0.05)
                if stop_requested['signal'] is not None:
                    raise KeyboardInterrupt
                if procs['controller_node'].poll() is not None:
                    raise DemoError(
                        'controller_node exited early with code '
                        f'{procs["controller_node"].returncode}:\n'
                        + tail(logs['controller_node'])
                    )
                now = time.monotonic()
                seen = recorder.message_counts.get(clock_topic, 0)
                if seen != ticks:
                    ticks, last_progress = seen, now
                limit = STALL_TIMEOUT_S if ticks else STARTUP_TIMEOUT_S
                if now - last_progress > limit:
                    raise DemoError(
                        f'sim_node published no {clock_topic} for {limit:.0f} s of wall time '
                        + (
                            f'after {ticks} ticks'
                            if ticks
                            else 'from its start (scene loading and JIT compilation)'
                        )
                        + ':\n'
                        + tail(logs['sim_node'])
                    )
        except KeyboardInterrupt:
            interrupted = True
        # drain what is still in flight
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
    finally:
        for name in ('sim_node', 'controller_node'):
            if name in procs:
                codes[name] = stop_process(procs[name])
        for f in files:
            f.close()
        if recorder is not None:
            recorder.close()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
        for sig, handler in previous.items():
            signal.signal(sig, handler)

    count = recorded_messages(recorder)
    if interrupted:
        log('interrupted: the nodes were stopped')
        if count != 0 and out.exists():
            return {
                'mcap': out,
                'codes': codes,
                'messages': count,
                'logs': logs,
                'interrupted': True,
            }
        raise KeyboardInterrupt
    if codes.get('sim_node') != 0:
        raise DemoError(
            f'sim_node failed with exit code {codes.get("sim_node")}:\n' + tail(logs['sim_node'])
        )
    if codes.get('controller_node') not in (0, -signal.SIGINT):
        raise DemoError(
            f'controller_node failed with exit code {codes.get("controller_node")}:\n'
            + tail(logs['controller_node'])
        )
    if not out.exists() or count == 0:
        raise DemoError(
            f'no data was recorded to {out} (the recorder saw no messages; '
            f'is discovery blocked? ROS_DOMAIN_ID={domain_id})'
        )
    return {'mcap': out, 'codes': codes, 'messages': count, 'logs': logs, 'interrupted': False}


def recorded_messages(recorder) -> int:
    """Return the number of messages the recorder wrote, if it tells; -1 if unknown."""
    for attr in ('message_counts', 'message_count', 'count'):
        v = getattr(recorder, attr, None)
        if v is None:
            continue
        if callable(v):
            v = v()
        if isinstance(v, dict):
            v = sum(v.values())
        try:
            return int(v)
        except (TypeError, ValueError):
            continue
    return -1


def default_out() -> Path:
    stamp = _dt.datetime.now().strftime('%Y%m%d-%H%M%S')
    return Path('runs') / f'demo-{stamp}.mcap'


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m pulsejet_sim.ros.demo', description=__doc__.strip().split('\n')[0]
    )
    parser.add_argument(
        '--scene', default=DEFAULT_SCENE, help='scene name under config/ or a YAML path'
    )
    parser.add_argument(
        '--duration', type=float, default=10.0, help='simulated seconds (default 10)'
    )
    parser.add_argument(
        '--real-time-factor', type=float, default=1.0, help='simulated s per wall s (default 1)'
    )
    parser.add_argument('--publish-rate', type=float, default=0.0, help='Hz; 0 = scene value')
    parser.add_argument(
        '--out', type=Path, default=None, help='MCAP file (default runs/demo-<timestamp>.mcap)'
    )
    args = parser.parse_args(argv)
    out = args.out or default_out()
    try:
        result = run_demo(args.scene, args.duration, args.real_time_factor, out, args.publish_rate)
    except DemoError as exc:
        print(f'demo failed: {exc}', file=sys.stderr, flush=True)
        return 1
    except KeyboardInterrupt:
        print('demo interrupted', file=sys.stderr)
        return 130
    from pulsejet_sim import analysis

    mcap = result['mcap']
    try:
        summary = analysis.summarize(mcap)
    except (
        Exception
    ) as exc:  # noqa: BLE001 - report what was recorded and why it could not be read
        print(f'demo failed: could not read {mcap}: {type(exc).__name__}: {exc}', file=sys.stderr)
        return 1
    print(analysis.format_summary(summary), flush=True)
    png = analysis.plot(mcap)
    png = Path(png) if png else mcap.with_suffix('.png')
    print(f'recording: {mcap}')
    print(f'plot:      {png}')
    if result.get('interrupted'):
        print('demo interrupted: the recording above is partial', file=sys.stderr)
        return 130
    return 0


if __name__ == '__main__':
    sys.exit(main())
