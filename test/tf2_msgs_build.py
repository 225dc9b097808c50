"""
Build tf2_msgs' TFMessage for rclpy from its definition, with the rosidl toolchain of the venv.

Every ROS install has tf2_msgs; the PyPI wheels this project runs on do not. So that the /tf path
of sim_node is tested with the real message type (real CDR over real DDS), this builds the Python
message package the way colcon does (rosidl_generator_py_generate_interfaces.cmake): the
interface translated to IDL, the C structs, the C type supports (introspection, Fast DDS and the
dispatcher), the Python module and its C extension, compiled with the system compiler against the
headers and libraries of the installed geometry_msgs and rosidl runtime.

build(root) -> (python path, library path): put the first on PYTHONPATH and the second on
LD_LIBRARY_PATH (the type support dispatcher loads its implementations by name from there) of the
process that imports tf2_msgs. RuntimeError says which step failed.
"""

from __future__ import annotations

import os
from pathlib import Path
import subprocess
import sys
import sysconfig

PACKAGE = 'tf2_msgs'
#: tf2_msgs/msg/TFMessage.msg, as the tf2_msgs package defines it
TF_MESSAGE_MSG = 'geometry_msgs/TransformStamped[] transforms\n'
PREFIX = Path(sys.prefix)  # the venv: share/ holds the .idl files, include/ and lib/ the rest
#: packages whose headers the generated sources include (include/<pkg>/<pkg>/... layout)
HEADER_PACKAGES = (
    'builtin_interfaces',
    'fastcdr',
    'geometry_msgs',
    'rcutils',
    'rmw',
    'rosidl_dynamic_typesupport',
    'rosidl_runtime_c',
    'rosidl_runtime_cpp',
    'rosidl_typesupport_c',
    'rosidl_typesupport_fastrtps_c',
    'rosidl_typesupport_fastrtps_cpp',
    'rosidl_typesupport_interface',
    'rosidl_typesupport_introspection_c',
    'std_msgs',
)


def _generate(root: Path) -> None:
    """Run the generators (as `rosidl generate` would; its CLI trips on duplicate entry points)."""
    from rosidl_generator_c.cli import GenerateC
    from rosidl_generator_py.cli import GeneratePython
    from rosidl_typesupport_c.cli import GenerateCTypesupport
    from rosidl_typesupport_fastrtps_c.cli import GenerateFastRTPSCTypesupport
    from rosidl_typesupport_introspection_c.cli import GenerateIntrospectionCTypesupport

    source = root / 'src'
    (source / 'msg').mkdir(parents=True, exist_ok=True)
    (source / 'msg' / 'TFMessage.msg').write_text(TF_MESSAGE_MSG)
    files = [f'{source}:msg/TFMessage.msg']
    include = [str(PREFIX / 'share')]
    typesupports = [
        'rosidl_typesupport_c',
        'rosidl_typesupport_fastrtps_c',
        'rosidl_typesupport_introspection_c',
    ]
    for kind, generator in (
        ('c', GenerateC('c')),
        ('typesupport_c', GenerateCTypesupport('c')),
        ('introspection_c', GenerateIntrospectionCTypesupport('introspection_c')),
        ('fastrtps_c', GenerateFastRTPSCTypesupport('fastrtps_c')),
        ('py', GeneratePython('py', typesupport_implementations=typesupports)),
    ):
        generator.generate(PACKAGE, files, include, root / 'gen' / kind / PACKAGE)


def _compile(output: Path, sources: list[Path], links: list[str], root: Path) -> None:
    cpp = any(s.suffix == '.cpp' for s in sources)
    includes = [f'-I{root / "gen" / kind}' for kind in ('c', 'introspection_c', 'fastrtps_c')]
    includes += [f'-I{PREFIX / "include" / pkg}' for pkg in HEADER_PACKAGES]
    includes += [f'-I{PREFIX / "include"}']  # fastcdr's headers are not nested
    includes += [f'-I{sysconfig.get_paths()["include"]}']
    import numpy

    includes += [f'-I{numpy.get_include()}']
    command = (
        ['g++', '-std=c++17'] if cpp else ['gcc']
    ) + [
        '-shared',
        '-fPIC',
        '-O1',
        '-w',
        *includes,
        *map(str, sources),
        f'-L{root / "lib"}',
        f'-L{PREFIX / "lib"}',
        f'-Wl,-rpath,{root / "lib"}:{PREFIX / "lib"}',
        f'-Wl,-soname,{output.name}',  # so that a library already loaded is found by its name
        *[f'-l{lib}' for lib in links],
        '-o',
        str(output),
    ]
    proc = subprocess.run(command, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f'compiling {output.name} failed:\n{proc.stderr[-4000:]}')


def build(root: Path) -> tuple[Path, Path]:
    """Generate and compile tf2_msgs under `root`; return (python path, library path)."""
    env_prefix = os.environ.get('AMENT_PREFIX_PATH')
    os.environ['AMENT_PREFIX_PATH'] = str(PREFIX)  # where the generators find their templates
    try:
        _generate(root)
    finally:
        if env_prefix is None:
            del os.environ['AMENT_PREFIX_PATH']
        else:
            os.environ['AMENT_PREFIX_PATH'] = env_prefix
    gen = root / 'gen'
    lib = root / 'lib'
    lib.mkdir(exist_ok=True)
    c_lib = f'{PACKAGE}__rosidl_generator_c'
    _compile(
        lib / f'lib{c_lib}.so',
        sorted((gen / 'c' / PACKAGE / 'msg' / 'detail').glob('*.c')),
        ['geometry_msgs__rosidl_generator_c', 'rosidl_runtime_c', 'rcutils'],
        root,
    )
    _compile(
        lib / f'lib{PACKAGE}__rosidl_typesupport_introspection_c.so',
        sorted((gen / 'introspection_c' / PACKAGE / 'msg' / 'detail').glob('*.c')),
        [c_lib, 'geometry_msgs__rosidl_typesupport_introspection_c', 'rosidl_runtime_c'],
        root,
    )
    _compile(
        lib / f'lib{PACKAGE}__rosidl_typesupport_fastrtps_c.so',
        sorted((gen / 'fastrtps_c' / PACKAGE / 'msg' / 'detail').glob('*.cpp')),
        [
            c_lib,
            'geometry_msgs__rosidl_typesupport_fastrtps_c',
            'geometry_msgs__rosidl_generator_c',
            'rosidl_typesupport_fastrtps_c',
            'rosidl_typesupport_fastrtps_cpp',
            'rosidl_runtime_c',
            'fastcdr',
            'rmw',
            'rcutils',
        ],
        root,
    )
    _compile(
        lib / f'lib{PACKAGE}__rosidl_typesupport_c.so',
        sorted((gen / 'typesupport_c' / PACKAGE / 'msg').glob('*.cpp')),
        [c_lib, 'rosidl_typesupport_c', 'rosidl_runtime_c', 'rcpputils', 'rcutils'],
        root,
    )
    py = gen / 'py' / PACKAGE
    py_lib = f'{PACKAGE}__rosidl_generator_py'
    _compile(
        lib / f'lib{py_lib}.so',
        sorted((py / 'msg').glob('*_s.c')),
        [c_lib, 'geometry_msgs__rosidl_generator_py', 'geometry_msgs__rosidl_generator_c',
         'rosidl_runtime_c'],
        root,
    )
    (py / '__init__.py').touch()
    for support in ('rosidl_typesupport_c',):
        _compile(
            py / f'{PACKAGE}_s__{support}{sysconfig.get_config_var("EXT_SUFFIX")}',
            [py / f'_{PACKAGE}_s.ep.{support}.c'],
            [py_lib, f'{PACKAGE}__{support}', c_lib, 'rosidl_runtime_c'],
            root,
        )
    return gen / 'py', lib
