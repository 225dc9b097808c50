"""
ament_python build of pulsejet_sim (colcon build, ros2 run pulsejet_sim <executable>).

After installing, `setup.py install` (colcon build) and `setup.py develop` (colcon build
--symlink-install) compile the physics kernels of every shipped scene into numba's on-disk cache
for the installed copy (pulsejet_sim/engine/warmup.py, in a subprocess), so that the first start of
sim_node does not spend ~20 s compiling.  A failed warm-up prints a warning and never fails the
build (the node then compiles at its first start).  PULSEJET_SKIP_NUMBA_WARMUP=1 skips it; an
install into a staging --root (wheels, Debian packages) skips it too: numba's cache belongs to the
machine (its CPU) that runs the installed files.
"""

from glob import glob
import os
import subprocess
import sys
import time

from setuptools import Command, find_packages, setup
from setuptools.command.install import install

try:
    from setuptools.command.develop import develop
except (
    ImportError
):  # a setuptools without `develop`: colcon --symlink-install then falls back to install
    develop = None

PACKAGE = 'pulsejet_sim'
HERE = os.path.dirname(os.path.abspath(__file__))
SKIP_WARMUP_ENV = 'PULSEJET_SKIP_NUMBA_WARMUP'
WARMUP_TIMEOUT_ENV = 'PULSEJET_NUMBA_WARMUP_TIMEOUT_S'
# run in a fresh interpreter with the installed tree first on sys.path (not the source tree)
_WARMUP_CODE = (
    'import sys; sys.path.insert(0, sys.argv[1]); '
    'from pulsejet_sim.engine.warmup import main; sys.exit(main(sys.argv[2:]))'
)


def warm_numba_cache(import_root):
    """
    Run pulsejet_sim.engine.warmup against the package importable from import_root.

    One log line. Returns the cache files written under import_root (for the install record);
    never raises.
    """
    tag = f'{PACKAGE}: numba compile cache'
    if os.environ.get(SKIP_WARMUP_ENV, '') not in ('', '0'):
        print(
            f'{tag}: not warmed ({SKIP_WARMUP_ENV} is set); sim_node compiles its kernels at first'
            ' start',
            flush=True,
        )
        return []
    import_root = os.path.abspath(import_root)
    cmd = [
        sys.executable,
        '-c',
        _WARMUP_CODE,
        import_root,
        '--quiet',
        '--list-cache-files',
        '--expect-root',
        import_root,
        '--config-dir',
        os.path.join(HERE, 'config'),
    ]
    t0 = time.monotonic()
    try:
        timeout = float(os.environ.get(WARMUP_TIMEOUT_ENV, '') or 1800)
        proc = subprocess.run(
            cmd,
            cwd=import_root,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            timeout=timeout,
        )
    except subprocess.TimeoutExpired as exc:
        reason = f'timed out after {exc.timeout:g} s ({WARMUP_TIMEOUT_ENV})'
    except (OSError, ValueError, subprocess.SubprocessError) as exc:
        reason = f'{type(exc).__name__}: {exc}'
    else:
        lines = proc.stdout.splitlines()
        summary = next(
            (line for line in lines if line.startswith('pulsejet_warmup:')), ''
        ).partition(': ')[2]
        root = os.path.realpath(import_root)
        written = [
            line
            for line in lines
            if line.endswith(('.nbi', '.nbc')) and os.path.realpath(line).startswith(root + os.sep)
        ]
        if proc.returncode == 0:
            print(f'{tag}: {summary or "warmed"}', flush=True)
            return written
        errors = [line for line in proc.stderr.splitlines() if line.strip()]
        reason = f'exit status {proc.returncode}: ' + (' | '.join(errors[-3:]) or 'no output')
        if summary:  # some scenes warmed, some failed
            print(
                f'WARNING: {tag} only partly warmed ({summary}; {reason}); the build goes on,'
                ' sim_node compiles what is missing at first start',
                file=sys.stderr,
                flush=True,
            )
            return written
    print(
        f'WARNING: {tag} not warmed after {time.monotonic() - t0:.0f} s ({reason}); the build goes'
        ' on, sim_node compiles its kernels at first start',
        file=sys.stderr,
        flush=True,
    )
    return []


class warm_numba_cache_command(Command):
    """Install sub-command: warm numba's cache for the files install_lib just installed."""

    description = (
        "compile the physics kernels of the shipped scenes into numba's cache (installed copy)"
    )
    user_options = []

    def initialize_options(self):
        self.install_dir = None
        self.root = None
        self.outputs = []

    def finalize_options(self):
        self.set_undefined_options('install', ('install_lib', 'install_dir'), ('root', 'root'))

    def run(self):
        if (
            self.root
        ):  # a staging tree (bdist_wheel, Debian packaging): neither the final place nor machine
            print(
                f'{PACKAGE}: numba compile cache not warmed (installing into the staging root'
                f' {self.root})',
                flush=True,
            )
            return
        self.outputs = warm_numba_cache(self.install_dir)

    def get_outputs(self):
        return self.outputs  # in the --record list, so colcon removes them with the rest


class install_and_warm(install):
    """
    `setup.py install` (colcon build), then the warm-up as the last sub-command.

    install_lib has put the package in place by then.
    """

    sub_commands = install.sub_commands + [('warm_numba_cache', None)]


CMDCLASS = {'install': install_and_warm, 'warm_numba_cache': warm_numba_cache_command}

if develop is not None:

    class develop_and_warm(develop):
        """
        `setup.py develop`, then the warm-up against the develop path.

        For colcon build --symlink-install.
        """

        def run(self):
            super().run()
            egg_path = getattr(self, 'egg_path', None)
            if getattr(self, 'uninstall', False) or not egg_path:
                # uninstalling, or a setuptools whose develop is `pip install -e` (no egg path)
                return
            warm_numba_cache(os.path.join(getattr(self, 'install_dir', None) or '', egg_path))

    CMDCLASS['develop'] = develop_and_warm


setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'benchmarks', 'benchmarks.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
        ('share/' + PACKAGE + '/config/sweeps', glob('config/sweeps/*.yaml')),
        ('share/' + PACKAGE + '/config/optimize', glob('config/optimize/*.yaml')),
        ('share/' + PACKAGE + '/config/params', glob('config/params/*.yaml')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    # `pulsejet sweep|optimize --scheduler tcp://HOST:PORT | --dask-workers N`; `pulsejet view`
    # (Foxglove WebSocket live view); pinned in requirements.txt
    extras_require={'dask': ['dask[distributed]'], 'view': ['foxglove-sdk']},
    zip_safe=True,
    maintainer='pulsejet maintainers',
    maintainer_email='maintainers@pulsejet.dev',
    description='Soft pulsed-jet underwater robot simulator for ROS 2',
    license='Apache-2.0',
    tests_require=['pytest'],
    cmdclass=CMDCLASS,
    entry_points={
        'console_scripts': [
            'sim_node = pulsejet_sim.ros.sim_node:main',
            'controller_node = pulsejet_ctrl.controller_node:main',
            'recorder = pulsejet_sim.ros.recorder:main',
            'replay = pulsejet_sim.ros.replay:main',
            'pulsejet = pulsejet_sim.cli:main',
            'pulsejet_warmup = pulsejet_sim.engine.warmup:main',
        ],
    },
)
