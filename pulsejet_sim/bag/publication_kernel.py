"""
The numba kernel of bag.publications: a stretch of publications written into one MCAP buffer.

One call per chunk instead of a few hundred numpy calls on small arrays (each a few us on a
loaded machine, which was most of what laying out a chunk cost). The bytes are the ones
PublicationLayout documents and test_recording compares message by message: each record a copy
of its template with the varying fields written over it, little endian (as MCAP and CDR are).
"""

from __future__ import annotations

from numba import njit
import numpy as np

# MCAP Message record head: opcode u8, length u64, channel u16, then at these offsets
_SEQUENCE, _LOG_TIME, _PUBLISH_TIME, _HEAD_SIZE = 11, 15, 23, 31
_NS_PER_S = 1_000_000_000


@njit(cache=True, nogil=True, inline='always')
def _put(out, at, value, size):
    """Write a non-negative integer as size bytes, little endian (indexing as _copy does)."""
    dest = out[at:at + size]
    for i in range(size):
        dest[i] = (value >> (8 * i)) & 0xFF


@njit(cache=True, nogil=True, inline='always')
def _copy(out, at, data):
    """
    Copy data into out from at.

    An element loop on a slice of out, indexed from 0 up: about four times faster than numba's
    slice assignment, and than indexing out at at + i (a possibly negative index, checked).
    """
    dest = out[at:at + len(data)]
    for i in range(len(data)):
        dest[i] = data[i]


@njit(cache=True, nogil=True)
def lay_out(
    out, template_c, c_starts, c_columns, c_sequence, template_a, a_positions, a_sequence,
    template_s, s_starts, s_sequence, stamp_ats, value_ats, value_columns, profile_at,
    commanded, applied, command_ns, commands, state_ns, states, r_m, z_m,
    ledger_data, ledger_bounds, ledger_channel, ledger_sequence,
    index_c, index_a, index_s, index_l,
):
    """
    Write n publications' records into out; return (bytes, commanded, applied, ledgers) written.

    Per publication: its commands (a record per c_starts, when commanded), the applied command
    (when applied), the state (a record per s_starts), the energy ledger (when ledger_bounds
    gives it bytes). c/a/s/ledger_sequence: each channel's message count before the stretch;
    index_c/a/s/l: filled with (log time, offset) per message, channel by channel.
    """
    scratch = np.empty(1, dtype=np.float64)
    scratch_bytes = scratch.view(np.uint8)
    single = np.empty(1, dtype=np.float32)
    single_bytes = single.view(np.uint8)
    wc, wa, ws = len(template_c), len(template_a), len(template_s)
    points = r_m.shape[1]
    pos = 0
    kc = 0
    ka = 0
    kl = 0
    for row in range(len(state_ns)):
        if commanded[row]:
            ns = command_ns[row]
            _copy(out, pos, template_c)
            for j in range(len(c_starts)):
                at = pos + c_starts[j]
                _put(out, at + _SEQUENCE, c_sequence[j] + kc + 1, 4)
                _put(out, at + _LOG_TIME, ns, 8)
                _put(out, at + _PUBLISH_TIME, ns, 8)
                scratch[0] = commands[row, c_columns[j]]
                _copy(out, at + _HEAD_SIZE + 4, scratch_bytes)
                index_c[j, kc, 0] = ns
                index_c[j, kc, 1] = at
            kc += 1
            pos += wc
            if applied[row]:
                _copy(out, pos, template_a)
                _put(out, pos + _SEQUENCE, a_sequence + ka + 1, 4)
                _put(out, pos + _LOG_TIME, ns, 8)
                _put(out, pos + _PUBLISH_TIME, ns, 8)
                _put(out, pos + _HEAD_SIZE + 4, ns // _NS_PER_S, 4)
                _put(out, pos + _HEAD_SIZE + 8, ns % _NS_PER_S, 4)
                for i in range(commands.shape[1]):
                    scratch[0] = commands[row, i]
                    _copy(out, pos + a_positions + 8 * i, scratch_bytes)
                index_a[ka, 0] = ns
                index_a[ka, 1] = pos
                ka += 1
                pos += wa
        ns = state_ns[row]
        _copy(out, pos, template_s)
        for j in range(len(s_starts)):
            at = pos + s_starts[j]
            _put(out, at + _SEQUENCE, s_sequence[j] + row + 1, 4)
            _put(out, at + _LOG_TIME, ns, 8)
            _put(out, at + _PUBLISH_TIME, ns, 8)
            index_s[j, row, 0] = ns
            index_s[j, row, 1] = at
        for at in stamp_ats:  # builtin_interfaces/Time: int32 s (non-negative), uint32 ns
            _put(out, pos + at, ns // _NS_PER_S, 4)
            _put(out, pos + at + 4, ns % _NS_PER_S, 4)
        for j in range(len(value_ats)):
            scratch[0] = states[row, value_columns[j]]
            _copy(out, pos + value_ats[j], scratch_bytes)
        for p in range(points):  # Point32: x = axial position, y = radius, z = 0 (template)
            at = pos + profile_at + 12 * p
            single[0] = z_m[row, p]
            _copy(out, at, single_bytes)
            single[0] = r_m[row, p]
            _copy(out, at + 4, single_bytes)
        pos += ws
        start, stop = ledger_bounds[row], ledger_bounds[row + 1]
        if stop > start:
            size = stop - start
            out[pos] = 5
            _put(out, pos + 1, _HEAD_SIZE - 9 + size, 8)
            _put(out, pos + 9, ledger_channel, 2)
            _put(out, pos + _SEQUENCE, ledger_sequence + kl + 1, 4)
            _put(out, pos + _LOG_TIME, ns, 8)
            _put(out, pos + _PUBLISH_TIME, ns, 8)
            _copy(out, pos + _HEAD_SIZE, ledger_data[start:stop])
            index_l[kl, 0] = ns
            index_l[kl, 1] = pos
            kl += 1
            pos += _HEAD_SIZE + size
    return pos, kc, ka, kl


@njit(cache=True, nogil=True)
def stamps_and_changes(rows, state_column, last, has_last):
    """
    Return the stamps of a stretch's rows and which publish the applied command.

    rows: (n, columns) float64: the commands' time in s (negative: no commands), the command
    values from column 1 to state_column, the state's time in s at state_column (times checked
    by the caller: finite, in [0, 2^31) s). last: the command held before the stretch (has_last:
    one is). Returns (command_ns, -1 where no commands; state_ns; applied: the command differs
    from the one held before it; the last command held, whether one is), the ns rounded as
    cdr.stamps_ns rounds them (np.rint of s * 1e9).
    """
    n = rows.shape[0]
    command_ns = np.empty(n, dtype=np.int64)
    state_ns = np.empty(n, dtype=np.int64)
    applied = np.zeros(n, dtype=np.bool_)
    held = last.copy()
    for row in range(n):
        t = rows[row, 0]
        if t >= 0.0:
            command_ns[row] = np.int64(np.rint(t * 1e9))
            changed = not has_last
            for j in range(1, state_column):
                if rows[row, j] != held[j - 1]:
                    changed = True
                held[j - 1] = rows[row, j]
            applied[row] = changed
            has_last = True
        else:
            command_ns[row] = -1
        state_ns[row] = np.int64(np.rint(rows[row, state_column] * 1e9))
    return command_ns, state_ns, applied, held, has_last
