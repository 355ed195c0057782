"""Recovery of killed recordings: a bag without ``metadata.yaml`` or MCAP summary, whose last
chunk is cut, rebuilt into a normal bag from every complete record.
"""
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from mcap.exceptions import McapError
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader

from grass_nrsfm_ros.bag.messages import BagError
from grass_nrsfm_ros.bag.write import BagWriter, DEFAULT_CHUNK_SIZE


@dataclass
class RecoveryReport:
    """What :func:`recover` rescued: messages per topic, and where reading stopped."""

    out_path: Path
    counts: Counter = field(default_factory=Counter)
    files: list = field(default_factory=list)
    stopped: list = field(default_factory=list)     # one line per file that ended early

    @property
    def messages(self):
        return sum(self.counts.values())


def mcap_files(bag_path):
    """The .mcap files of a bag directory (in split order) or ``[bag_path]`` for a file."""
    bag_path = Path(bag_path)
    if not bag_path.exists():
        raise FileNotFoundError(f'{bag_path} does not exist')
    if bag_path.is_file():
        return [bag_path]
    files = sorted(bag_path.glob('*.mcap'),
                   key=lambda p: (len(p.name), p.name))     # NAME_2 before NAME_10
    if not files:
        raise BagError(f'{bag_path} holds no .mcap file (only MCAP recordings can be recovered)')
    return files


def recover(bag_path, out_path=None, *, chunk_size=DEFAULT_CHUNK_SIZE):
    """Rebuild a killed recording (no metadata.yaml, no summary, truncated last chunk) into a
    normal bag at ``out_path`` (default ``<bag>_recovered``) holding every complete message.

    Reads each .mcap sequentially (``mcap.stream_reader.StreamReader``, CRCs checked) up to
    the first truncated or damaged record. Returns a :class:`RecoveryReport`.
    """
    files = mcap_files(bag_path)
    src = Path(bag_path)
    stem = src.stem if src.is_file() else src.name
    out = Path(out_path) if out_path else src.with_name(f'{stem}_recovered')
    report = RecoveryReport(out_path=out)
    with BagWriter(out, chunk_size=chunk_size) as writer:
        for path in files:
            report.files.append(path.name)
            schemas, channels = {}, {}
            with open(path, 'rb') as fh:
                try:
                    for rec in StreamReader(fh, validate_crcs=True).records:
                        if isinstance(rec, Schema):
                            schemas[rec.id] = rec
                        elif isinstance(rec, Channel):
                            channels[rec.id] = rec
                            schema = schemas[rec.schema_id]
                            writer.add_topic(rec.topic, schema.name,
                                             definition=schema.data.decode(),
                                             qos=rec.metadata.get('offered_qos_profiles', ''))
                        elif isinstance(rec, Message):
                            topic = channels[rec.channel_id].topic
                            writer.write(topic, rec.data, rec.log_time, rec.publish_time)
                            report.counts[topic] += 1
                except (McapError, KeyError, ValueError, UnicodeDecodeError) as exc:
                    name = type(exc).__name__
                    report.stopped.append(f'{path.name}: stopped at byte {fh.tell()} ({name}'
                                          f'{": " + str(exc) if str(exc) else ""})')
    return report
