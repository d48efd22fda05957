"""Read a rig dataset with the PyPI `mcap` and `mcap-protobuf-support` packages (readers the
rig's authors did not write), through the files' summary and index.

Usage: mcap_check.py DIR EXPECTED_JSON
EXPECTED_JSON maps file name -> {"counts": {topic: message count},
                                  "schemas": {topic: schema name}}.
Per file: the summary exists and has chunk indexes and statistics whose per-channel counts are
the expected ones; the indexed reader (a seekable file: it reads the chunks the summary points
to, CRCs validated) returns every message of every channel, with the expected counts and schema
names, every channel protobuf; every message decodes with the file's own descriptors; every
frame is a PNG or JPEG (by its magic bytes); where the file holds the simulator's true wrench
(`/sim/true_wrench`), each one is for a recorded frame and every recorded frame has exactly one.
Prints one line per file (its counts) and exits non-zero on any mismatch.
"""

import json
import os
import sys

try:
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory
except ImportError:
    print("the Python `mcap` or `mcap-protobuf-support` package is missing: run "
          "`bash scripts/test` (it installs tests/python/requirements.txt into .venv)",
          file=sys.stderr)
    sys.exit(3)

TRUTH = "/sim/true_wrench"
MAGIC = {"png": b"\x89PNG\r\n\x1a\n", "jpeg": b"\xff\xd8\xff"}


def check_file(path: str, want: dict) -> list:
    """The problems found in one file (empty when it matches)."""
    problems = []
    counts = {}
    schemas = {}
    frame_seqs = []
    truth_seqs = []
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        if summary is None:
            return ["no summary section"]
        if not summary.chunk_indexes:
            problems.append("no chunk indexes in the summary")
        if summary.statistics is None:
            return problems + ["no statistics in the summary"]
        stats = {summary.channels[cid].topic: n
                 for cid, n in summary.statistics.channel_message_counts.items() if n > 0}
        if stats != want["counts"]:
            problems.append(f"summary statistics {stats}, want {want['counts']}")
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            topic = channel.topic
            counts[topic] = counts.get(topic, 0) + 1
            schemas[topic] = schema.name
            if (schema.encoding, channel.message_encoding) != ("protobuf", "protobuf"):
                problems.append(f"{topic}: encodings {schema.encoding}/{channel.message_encoding}")
            if topic == "/camera/image":
                if not decoded.data.startswith(MAGIC.get(decoded.format, b"?")):
                    problems.append(f"frame {message.sequence}: not a {decoded.format} image")
                frame_seqs.append(message.sequence)
            elif topic == TRUTH:
                if not (decoded.HasField("force") and decoded.HasField("torque")):
                    problems.append(f"{TRUTH}: not a true wrench: {decoded}")
                truth_seqs.append(decoded.frame_seq)
    print(f"{os.path.basename(path)}: {json.dumps(counts, sort_keys=True)}")
    if counts != want["counts"]:
        problems.append(f"got counts {counts}, want {want['counts']}")
    if schemas != want["schemas"]:
        problems.append(f"got schemas {schemas}, want {want['schemas']}")
    if truth_seqs and sorted(truth_seqs) != sorted(frame_seqs):
        problems.append(f"true wrench frames {sorted(truth_seqs)} != recorded frames {sorted(frame_seqs)}")
    return problems


def main() -> int:
    directory, expected = sys.argv[1], json.loads(sys.argv[2])
    bad = 0
    for name, want in sorted(expected.items()):
        for p in check_file(os.path.join(directory, name), want):
            print(f"{name}: {p}", file=sys.stderr)
            bad += 1
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
