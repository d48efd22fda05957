"""Read a rig dataset with the PyPI `mcap` package (a reader the rig's authors did not write).

Usage: mcap_check.py DIR EXPECTED_JSON
EXPECTED_JSON maps file name -> {"counts": {topic: message count},
                                  "schemas": {topic: schema name}}.
Checks every file's per-topic message counts and schema names (every channel JSON with a
jsonschema schema), that every frame is a PNG, and, where the file holds the simulator's true
wrench (`/sim/true_wrench`), that each message is a wrench for a recorded frame and that every
recorded frame has exactly one. Prints one line per file (its counts) and exits non-zero on any
mismatch.
"""

import json
import os
import sys

try:
    from mcap.reader import make_reader
except ImportError:
    print("the Python `mcap` package is missing: run `bash scripts/test` (it installs "
          "tests/python/requirements.txt into .venv)", file=sys.stderr)
    sys.exit(3)

TRUTH = "/sim/true_wrench"


def is_vec3(v) -> bool:
    return isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) for x in v)


def check_file(path: str, want: dict) -> list:
    """The problems found in one file (empty when it matches)."""
    problems = []
    counts = {}
    schemas = {}
    frame_seqs = []
    truth_seqs = []
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages():
            topic = channel.topic
            counts[topic] = counts.get(topic, 0) + 1
            schemas[topic] = schema.name
            if (schema.encoding, channel.message_encoding) != ("jsonschema", "json"):
                problems.append(f"{topic}: encodings {schema.encoding}/{channel.message_encoding}")
            body = json.loads(message.data)
            if topic == "/camera/image":
                if body["format"] != "png":
                    problems.append(f"frame {body.get('seq')}: format {body['format']}")
                frame_seqs.append(body["seq"])
            elif topic == TRUTH:
                if not (isinstance(body.get("frame_seq"), int) and is_vec3(body.get("force_n"))
                        and is_vec3(body.get("torque_nmm"))):
                    problems.append(f"{TRUTH}: not a true wrench: {body}")
                truth_seqs.append(body.get("frame_seq"))
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
