"""
Live fuzz of sim_node: floods its command topics, services and parameters and counts what breaks.

    .venv/bin/python -m benchmarks.reliability.live_fuzz [--seconds 600]
                                 [--scene pump_cycle --scene shell_robot]
                                 [--rate-hz 2000] [--seed 1] [--no-write]

For each scene a real sim_node runs as a process (real_time pacing, command watchdog on) in an
isolated ROS domain with localhost discovery. This process floods it at `--rate-hz` (>= 1 kHz)
with:
  - per-actuator commands (std_msgs/Float64) and atomic commands (sensor_msgs/JointState) whose
    values are drawn from in-range numbers, NaN, +-inf, 1e308, negatives and subnormals; atomic
    commands with unknown or missing names, mismatched lengths, no stamp, stamps in the past or the
    future (out of order), and exact duplicates;
  - pause / step / reset service calls at random (not waited for before the next message);
  - parameter changes (live, read-only and unknown parameters; valid, out-of-range, non-finite and
    wrongly typed values).
It checks every published state message for non-finite numbers, restarts sim_node if it dies
(counted: must stay 0), times the parameter services as `ros2 param dump` uses them, and samples
sim_node's resident memory. It prints a table and writes benchmarks/results/live_fuzz.md (and
live_fuzz.json, which benchmarks/reliability/reliability_table.py turns into its live row).
Not a test.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
import random
import re
import sys
import tempfile
import time


from benchmarks import common
from benchmarks.live import cpu_seconds, LiveClient, ParamProbe, rss_bytes
from pulsejet_sim.core import topics
from pulsejet_sim.ros.launching import (
    default_domain_id,
    discover_localhost_only,
    isolated_environment,
    NodeProcess,
)

WEIRD = (float('nan'), float('inf'), -float('inf'), 1e308, -1e308, -1.0, 5e-324, 0.0)
SERVICE_TIMEOUT_S = 10.0
PARAMETER_VALUES = {
    'pacing': [
        'real_time',
        'real_time',
        'real_time',
        'lockstep',
        'as_fast_as_possible',
        'closed_loop',
        'warp',
        3.0,
    ],
    'real_time_factor': [1.0, 1.0, 2.0, 0.5, 0.0, -1.0, float('nan'), float('inf'), 1e308, 'fast'],
    'step_count': [1, 100, 1000, 0, -5, 10**9, 'many'],
    'watchdog_timeout_s': [0.5, 0.0, 2.0, -1.0, float('nan'), float('inf')],
    'watchdog_clock': ['sim', 'wall', 'moon'],
    'watchdog_action': ['safe', 'hold', 'panic'],
    'scene': ['escape'],  # read-only: refused
    'publish_rate_hz': [50.0],  # read-only: refused
    'no_such_parameter': [1.0],
}


def actuator_value(rng: random.Random, field: str) -> float:
    """Mostly plausible values, one in four from the weird set."""
    if rng.random() < 0.25:
        return rng.choice(WEIRD)
    return {
        'pump_flow_m3_s': lambda: rng.uniform(-1e-3, 6e-3),
        'valve_opening': lambda: rng.uniform(-0.2, 1.2),
        'cable_force_n': lambda: rng.uniform(-5.0, 40.0),
    }[field]()


class Flood:
    """Publishers and service clients of the fuzzer, and the tally of what it sent."""

    def __init__(self, client: LiveClient, rng: random.Random):
        from rcl_interfaces.srv import SetParameters
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64
        from std_srvs.srv import SetBool, Trigger

        self.rng, self.client = rng, client
        node = client.node
        self.float_pubs = {
            topic: node.create_publisher(Float64, topic, client.qos)
            for topic in topics.COMMAND_TOPICS
        }
        self.command_pub = node.create_publisher(
            JointState, topics.TOPIC_CMD_COMMAND, client.qos
        )
        self.services = {
            'pause': node.create_client(SetBool, topics.SERVICE_PAUSE),
            'step': node.create_client(Trigger, topics.SERVICE_STEP),
            'reset': node.create_client(Trigger, topics.SERVICE_RESET),
            'set_parameters': node.create_client(SetParameters, '/sim_node/set_parameters'),
        }
        self.sent = {
            'actuator': 0,
            'atomic': 0,
            'duplicate': 0,
            'out_of_order': 0,
            'service': 0,
            'parameter': 0,
        }
        self.pending = []  # (future, kind, sent wall s)
        self.answers = {'accepted': 0, 'refused': 0, 'unanswered': 0}
        self._last_command = None

    def ready(self) -> bool:
        return all(c.service_is_ready() for c in self.services.values())

    def send_one(self) -> None:
        r = self.rng.random()
        if r < 0.45:
            self._actuator()
        elif r < 0.93:
            self._atomic()
        elif r < 0.98:
            self._service()
        else:
            self._parameter()

    def _actuator(self):
        from std_msgs.msg import Float64

        topic = self.rng.choice(topics.COMMAND_TOPICS)
        self.float_pubs[topic].publish(
            Float64(data=actuator_value(self.rng, topics.COMMAND_FIELDS[topic]))
        )
        self.sent['actuator'] += 1

    def _atomic(self):
        from sensor_msgs.msg import JointState

        rng = self.rng
        if self._last_command is not None and rng.random() < 0.1:
            self.command_pub.publish(self._last_command)
            self.sent['duplicate'] += 1
            return
        names = rng.sample(topics.APPLIED_COMMAND_NAMES, rng.randint(0, 3))
        if rng.random() < 0.05:
            names.append(
                rng.choice(['thrust', '', 'valve_opening ', 'pump_flow_m3_s'])
            )  # unknown or repeated
        msg = JointState()
        msg.name = names
        msg.position = [
            actuator_value(rng, n) if n in topics.APPLIED_COMMAND_NAMES else 1.0 for n in names
        ]
        if rng.random() < 0.05:
            msg.position = msg.position[:-1] or [1.0, 2.0]  # lengths differ
        now = self.client.last_clock_s or 0.0
        stamp = rng.choice([None, now, now - rng.uniform(0.0, 5.0), now + rng.uniform(0.0, 5.0)])
        if stamp is not None:
            if stamp < now:
                self.sent['out_of_order'] += 1
            stamp = max(stamp, 0.0)
            msg.header.stamp.sec = int(stamp)
            msg.header.stamp.nanosec = int((stamp - int(stamp)) * 1e9)
        self.command_pub.publish(msg)
        self._last_command = msg
        self.sent['atomic'] += 1

    def _service(self):
        from std_srvs.srv import SetBool, Trigger

        kind = self.rng.choice(['pause', 'pause', 'step', 'reset'])
        request = (
            SetBool.Request(data=self.rng.random() < 0.4) if kind == 'pause' else Trigger.Request()
        )
        self.pending.append((self.services[kind].call_async(request), kind, time.monotonic()))
        self.sent['service'] += 1

    def _parameter(self):
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        name = self.rng.choice(list(PARAMETER_VALUES))
        value = self.rng.choice(PARAMETER_VALUES[name])
        request = SetParameters.Request(
            parameters=[Parameter(name, value=value).to_parameter_msg()]
        )
        self.pending.append(
            (self.services['set_parameters'].call_async(request), 'parameter', time.monotonic())
        )
        self.sent['parameter'] += 1

    def collect(self, final: bool = False) -> None:
        """
        Count the answers.

        A call unanswered after SERVICE_TIMEOUT_S (or at the end) is unanswered.
        """
        keep = []
        now = time.monotonic()
        for future, kind, sent in self.pending:
            if future.done():
                result = future.result()
                ok = (
                    all(r.successful for r in result.results)
                    if kind == 'parameter'
                    else bool(result.success)
                )
                self.answers['accepted' if ok else 'refused'] += 1
            elif final or now - sent > SERVICE_TIMEOUT_S:
                self.answers['unanswered'] += 1
            else:
                keep.append((future, kind, sent))
        self.pending = keep


def restore(flood: Flood) -> None:
    """
    Put sim_node back to running real time.

    The next period of fuzzing then has a moving target.
    """
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter
    from std_srvs.srv import SetBool

    params = [Parameter('pacing', value='real_time'), Parameter('real_time_factor', value=1.0)]
    flood.pending.append(
        (
            flood.services['set_parameters'].call_async(
                SetParameters.Request(parameters=[p.to_parameter_msg() for p in params])
            ),
            'parameter',
            time.monotonic(),
        )
    )
    flood.pending.append(
        (
            flood.services['pause'].call_async(SetBool.Request(data=False)),
            'pause',
            time.monotonic(),
        )
    )


def fuzz_scene(
    scene: str, seconds: float, rate_hz: float, seed: int, domain: int, log_dir: Path
) -> dict:
    env = isolated_environment(domain)
    discover_localhost_only()  # this process's participant too
    params = {
        'scene': scene,
        'pacing': 'real_time',
        'watchdog_timeout_s': 0.5,
        'diagnostics_period_s': 0.5,
    }
    sim = NodeProcess('pulsejet_sim.ros.sim_node', params, log_dir / f'sim_node.{scene}.log', env)
    client = LiveClient(domain, f'live_fuzz_{scene}')
    flood = Flood(client, random.Random(seed))
    probe = ParamProbe(client.node)
    restarts, crash_tails = 0, []
    rss = []
    try:
        client.spin_until(
            lambda: flood.ready() and client.last_clock_s is not None,
            120.0,
            f'sim_node ({scene}) to start',
            [sim],
        )
        start = time.monotonic()
        cpu0 = cpu_seconds(sim.pid)
        end = start + seconds
        next_rss = start + min(
            10.0, seconds / 10
        )  # the first sample after warm-up is the baseline
        next_restore = start + 5.0
        period = 1.0 / rate_hz
        next_send = start
        while True:
            now = time.monotonic()
            if now >= end:
                break
            while next_send <= now:
                flood.send_one()
                next_send += period
            client.executor.spin_once(timeout_sec=0.0)
            probe.poll()
            if now >= next_rss:
                rss.append((now - start, rss_bytes(sim.pid)))
                next_rss += 5.0
            if now >= next_restore:
                flood.collect()
                restore(flood)
                next_restore += 5.0
            if not sim.alive():
                restarts += 1
                crash_tails.append(sim.output()[-1500:])
                sim = NodeProcess(
                    'pulsejet_sim.ros.sim_node',
                    params,
                    log_dir / f'sim_node.{scene}.{restarts}.log',
                    env,
                )
            delay = next_send - time.monotonic()
            if delay > 0.0005:
                time.sleep(min(delay, 0.001))
        wall = time.monotonic() - start
        cpu = (cpu_seconds(sim.pid) - cpu0) / wall
        client.spin(1.0)
        flood.collect(final=True)
    finally:
        exit_code = sim.stop()
        client.close()
    log = sim.output()
    logged = len(re.findall(r'rejected|command kept at', log))
    counts = {}
    for _, _, _, values in client.watch.diagnostics:
        counts = {k: values.get(f'commands_{k}', '?') for k in ('accepted', 'rejected', 'stale')}
    tracebacks = log.count('Traceback')
    diag = client.watch.diagnostics
    faults = sum(1 for _, level, msg, values in diag if level == 2)
    fault_messages = sorted({msg for _, level, msg, _ in diag if level == 2})[:5]
    sent_total = flood.sent['actuator'] + flood.sent['atomic'] + flood.sent['duplicate']
    base = rss[0][1] if rss else float('nan')
    last = rss[-1][1] if rss else float('nan')
    return {
        'scene': scene,
        'seconds': wall,
        'messages_sent': sent_total,
        'rate_hz': sent_total / wall,
        'sent': flood.sent,
        'service_answers': flood.answers,
        'rejections_logged': logged,
        'commands': counts,
        'cpu': cpu,
        'states_checked': client.watch.messages,
        'nan_published': client.watch.non_finite,
        'nan_examples': client.watch.examples,
        'error_diagnostics': faults,
        'error_messages': fault_messages,
        'restarts_needed': restarts,
        'crash_tails': crash_tails,
        'tracebacks_in_log': tracebacks,
        'exit_code': exit_code,
        'rss_start_mb': base / 2**20,
        'rss_end_mb': last / 2**20,
        'rss_max_mb': max((v for _, v in rss), default=float('nan')) / 2**20,
        'rss_growth': (last - base) / base if base > 0 else float('nan'),
        'param_services': probe.summary(),
    }


def table(results: list[dict]) -> str:
    rows = [
        ('scene', lambda r: r['scene']),
        ('wall time fuzzed', lambda r: f"{r['seconds']:.0f} s"),
        (
            'command messages sent (rate)',
            lambda r: f"{r['messages_sent']} ({r['rate_hz']:.0f} /s)",
        ),
        (
            'of which atomic / per-actuator / duplicates / stamped in the past',
            lambda r: f"{r['sent']['atomic']} / {r['sent']['actuator']} / "
            f"{r['sent']['duplicate']} / {r['sent']['out_of_order']}",
        ),
        (
            'commands accepted / rejected / stale (sim_node /diagnostics; warnings logged)',
            lambda r: '{accepted} / {rejected} / {stale}'.format(**r['commands'])
            + f" ({r['rejections_logged']})",
        ),
        ('sim_node CPU (user+sys / wall)', lambda r: f"{r['cpu']:.0%}"),
        (
            'service calls / parameter changes sent',
            lambda r: f"{r['sent']['service']} / {r['sent']['parameter']}",
        ),
        (
            'service and parameter answers: accepted / refused / unanswered',
            lambda r: '{accepted} / {refused} / {unanswered}'.format(**r['service_answers']),
        ),
        ('state messages checked', lambda r: str(r['states_checked'])),
        ('non-finite values published (must be 0)', lambda r: str(r['nan_published'])),
        ('ERROR diagnostics (physics faults)', lambda r: str(r['error_diagnostics'])),
        ('sim_node restarts needed (must be 0)', lambda r: str(r['restarts_needed'])),
        ('tracebacks in sim_node log', lambda r: str(r['tracebacks_in_log'])),
        ('sim_node exit code on SIGINT', lambda r: str(r['exit_code'])),
        (
            'sim_node RSS after warm-up -> end (max)',
            lambda r: f"{r['rss_start_mb']:.1f} -> {r['rss_end_mb']:.1f} MB "
            f"({r['rss_max_mb']:.1f}), {r['rss_growth']:+.1%}",
        ),
        (
            'parameter dump rounds (list + get): p50 / p99 / max, starved > 10 s',
            lambda r: '{rounds}: {p50_ms:.1f} / {p99_ms:.1f} / {max_ms:.1f} ms, {starved}'.format(
                **r['param_services']
            ),
        ),
    ]
    lines = [
        '| metric | ' + ' | '.join(r['scene'] for r in results) + ' |',
        '|---|' + '---|' * len(results),
    ]
    for label, get in rows[1:]:
        lines.append(f'| {label} | ' + ' | '.join(get(r) for r in results) + ' |')
    return '\n'.join(lines) + '\n'


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument(
        '--seconds', type=float, default=300.0, help='wall seconds of fuzzing per scene'
    )
    ap.add_argument(
        '--scene', action='append', help='scene(s) to fuzz (default pump_cycle and shell_robot)'
    )
    ap.add_argument(
        '--rate-hz', type=float, default=2000.0, help='command messages per wall second (>= 1000)'
    )
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--no-write', action='store_true', help='print only')
    args = ap.parse_args(argv)
    if not (args.rate_hz >= 1000.0 and math.isfinite(args.rate_hz)):
        ap.error(f'--rate-hz {args.rate_hz}: the fuzz must run at >= 1000 messages per second')
    if not args.seconds > 0:
        ap.error(f'--seconds {args.seconds}: must be > 0')
    scenes = args.scene or ['pump_cycle', 'shell_robot']
    domain = default_domain_id()
    results = []
    with tempfile.TemporaryDirectory(prefix='pulsejet_fuzz_') as tmp:
        for i, scene in enumerate(scenes):
            results.append(
                fuzz_scene(scene, args.seconds, args.rate_hz, args.seed + i, domain, Path(tmp))
            )
    command = 'python -m benchmarks.reliability.live_fuzz ' + ' '.join(
        sys.argv[1:] if argv is None else argv
    )
    text = common.header('Live fuzz of sim_node', command.strip()) + table(results)
    failed = [
        r['scene']
        for r in results
        if r['nan_published']
        or r['restarts_needed']
        or r['tracebacks_in_log']
        or r['exit_code'] != 0
    ]
    text += (
        '\nVerdict: '
        + (
            '0 non-finite values published, 0 restarts, no traceback, clean exit in every scene.'
            if not failed
            else f'FAILED in {", ".join(failed)}'
        )
        + '\n'
    )
    for r in results:
        for tail in r['crash_tails']:
            text += f'\nsim_node died ({r["scene"]}):\n```\n{tail}\n```\n'
        for message in r.get('error_messages', []):
            text += f'\nERROR diagnostic ({r["scene"]}): {message}\n'
        for example in r['nan_examples']:
            text += f'\nnon-finite ({r["scene"]}): {example}\n'
    if args.no_write:
        print(text)
    else:
        common.write('live_fuzz', text)
        (common.RESULTS / 'live_fuzz.json').write_text(
            json.dumps({'command': command.strip(), 'results': results}, indent=1, default=str)
            + '\n'
        )
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
