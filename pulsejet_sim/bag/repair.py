"""
`pulsejet repair FILE.mcap`: rewrite a damaged recording into a complete, indexed one.

A recorder killed hard (SIGKILL, a crash, the machine losing power) leaves an MCAP file without its
summary and footer, its last chunk possibly cut in half: rosbags (`File end magic is invalid`),
@mcap/core's indexed reader and mcap's `make_reader` refuse it. repair_file() reads the file front
to back with bag.reader (everything up to the last complete chunk; a corrupt chunk in the middle is
skipped) and writes a new file with BagWriter: summary, chunk and message indexes, statistics and
the `rosbag2` metadata record, so every reader opens it.

Nothing that was readable is lost: every schema (definition text verbatim), every channel with all
of its metadata verbatim (`offered_qos_profiles`, `topic_type_hash`, any other key), every message
with its log and publish times, every metadata record (e.g. the `pulsejet` scene of the run) and
every attachment. Only the old `rosbag2` metadata record (present only in a file that was closed)
is regenerated from the messages actually kept.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
import sys
from typing import Sequence
import warnings

from pulsejet_sim.bag.records import (
    BagInfo, BagReadError, check_header, iter_records, open_checked
)


@dataclass
class RepairResult:
    out_path: Path
    source: BagInfo  # what the damaged file held and what was cut (see BagInfo.damage_report)
    messages: int  # messages written to out_path
    skipped_channels: dict[str, str]  # topic -> why it could not be rewritten

    def report(self) -> str:
        lines = [
            f'repaired {self.source.path} -> {self.out_path}: {self.messages} messages on '
            f'{len(self.source.topics) - len(self.skipped_channels)} topics, '
            f'{len(self.source.metadata)} metadata record(s), channel metadata kept'
        ]
        damage = self.source.damage_report()
        lines.append(
            f'source: {damage}' if damage else 'source: was already complete (rewritten anyway)'
        )
        lines.extend(f'skipped topic {t}: {why}' for t, why in self.skipped_channels.items())
        return '\n'.join(lines)


def default_output(path: str | Path) -> Path:
    src = Path(path)
    return src.with_name(src.stem + '.repaired.mcap')


def repair_file(
    path: str | Path, out_path: str | Path | None = None, *, overwrite: bool = False
) -> RepairResult:
    """
    Rewrite `path` into `out_path` (default `<name>.repaired.mcap`).

    Raises BagReadError for a file that is not a readable ros2 MCAP recording at all, or an output
    that would replace the input (or an existing file without overwrite=True).
    """
    from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
    from pulsejet_sim.bag.writer import (  # local: reading never needs the writer
        BagError,
        BagWriter,
    )

    src = Path(path)
    out = Path(out_path) if out_path is not None else default_output(src)
    if out.resolve() == src.resolve():
        raise BagReadError(
            f'repair output {str(out)!r} rejected; allowed: a path other than the input file'
        )
    if out.exists() and not overwrite:
        raise BagReadError(
            f'repair output {str(out)!r} exists; allowed: a new path (or --force to replace it)'
        )
    p, fh = open_checked(src)
    info = BagInfo(p)
    schemas: dict[int, Schema] = {}
    channels: dict[int, str] = {}  # channel id -> topic as stored in the source
    skipped: dict[str, str] = {}
    written = 0
    tmp = out.with_name(out.name + '.partial')
    bag: BagWriter | None = None
    try:
        for record in iter_records(fh, info):
            if isinstance(record, Header):
                check_header(record, info, p, repairing=True)
                bag = BagWriter(tmp)
                continue
            if bag is None:  # the header record was damaged (the reader skipped it): keep the data
                bag = BagWriter(tmp)
            if isinstance(record, Schema):
                record = schemas.setdefault(
                    record.id, record
                )  # first copy wins (summary copies follow)
                info.definitions.setdefault(record.name, record.data.decode('utf-8', 'replace'))
            elif isinstance(record, Channel):
                if record.topic in info.channel_metadata and record.id in channels:
                    continue  # the summary's copy of a channel already added
                schema = schemas.get(record.schema_id)
                type_name = schema.name if schema else ''
                info.topics[record.topic] = type_name
                info.counts.setdefault(record.topic, 0)
                info.channel_metadata[record.topic] = dict(record.metadata)
                try:
                    if schema is None:
                        raise BagError(f'its schema (id {record.schema_id}) was lost')
                    if record.message_encoding != 'cdr':
                        raise BagError(f'message encoding {record.message_encoding!r} is not cdr')
                    bag.add_topic(
                        record.topic,
                        type_name,
                        definition=info.definitions[type_name],
                        channel_metadata=dict(record.metadata),
                    )
                    channels[record.id] = record.topic
                except (BagError, ValueError, LookupError) as err:
                    skipped[record.topic] = str(err)
            elif isinstance(record, Message):
                topic = channels.get(record.channel_id)
                if topic is None:
                    info.orphan_messages += 1
                    continue
                bag.write(topic, record.data, int(record.log_time), int(record.publish_time))
                info.counts[topic] = info.counts.get(topic, 0) + 1
                t = record.log_time
                info.first_log_ns = t if info.first_log_ns is None else min(info.first_log_ns, t)
                info.last_log_ns = t if info.last_log_ns is None else max(info.last_log_ns, t)
                written += 1
            elif isinstance(record, Metadata):
                info.metadata.append((record.name, dict(record.metadata)))
                if record.name != 'rosbag2':  # regenerated on close from what was kept
                    bag.add_metadata(record.name, dict(record.metadata))
            elif isinstance(record, Attachment):
                info.attachments.append(record)
                bag.add_attachment(
                    record.name,
                    record.data,
                    record.media_type,
                    record.log_time,
                    record.create_time,
                )
        if bag is None:
            raise BagReadError(f'{str(p)!r} holds no readable MCAP record; nothing to repair')
        bag.close()
        tmp.replace(out)
    finally:
        fh.close()
        if bag is not None and not bag.closed:
            bag.close()
        if tmp.exists():
            tmp.unlink()
    return RepairResult(out, info, written, skipped)


def main_repair(argv: Sequence[str] | None = None) -> int:
    """`pulsejet repair FILE.mcap [--out NEW.mcap] [--force]`. Exit 0 repaired, 2 bad input."""
    parser = argparse.ArgumentParser(
        prog='pulsejet repair',
        description='Rewrite a recording whose writer was killed hard (no summary, cut-off last '
                    'chunk) or '
        'that was damaged into a complete, indexed MCAP file that rosbags, ros2 bag and Foxglove '
        'open, keeping every readable message, channel metadata (QoS, type hash) and metadata '
        'record.',
    )
    parser.add_argument('file', help='damaged MCAP recording (.mcap)')
    parser.add_argument(
        '--out', default=None, help='output path (default: FILE.repaired.mcap next to FILE)'
    )
    parser.add_argument('--force', action='store_true', help='replace --out if it exists')
    args = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
    try:
        result = repair_file(args.file, args.out, overwrite=args.force)
    except BagReadError as err:
        print(f'pulsejet repair: error: {err}', file=sys.stderr)
        return 2
    except OSError as err:
        print(
            f'pulsejet repair: error: {str(err.filename or args.out)!r}: {err.strerror}',
            file=sys.stderr,
        )
        return 2
    print(result.report())
    return 0


if __name__ == '__main__':
    sys.exit(main_repair())


def repair(path: str | Path, out_path: str | Path | None = None) -> Path:
    """Rewrite a damaged recording into a complete one; see repair_file."""
    result = repair_file(path, out_path, overwrite=True)
    if not result.source.damaged:
        warnings.warn(f'{str(path)!r} was already complete; rewrote it anyway', stacklevel=2)
    return result.out_path
