"""Read a rig dataset with the PyPI `mcap` package (a reader the rig's authors did not write).

Usage: mcap_check.py DIR EXPECTED_JSON
EXPECTED_JSON maps file name -> {topic: message count}. Prints one line per file and exits
non-zero on any mismatch.
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


def main() -> int:
    directory, expected = sys.argv[1], json.loads(sys.argv[2])
    bad = 0
    for name, want in sorted(expected.items()):
        counts = {}
        schemas = {}
        with open(os.path.join(directory, name), "rb") as f:
            reader = make_reader(f)
            for schema, channel, message in reader.iter_messages():
                counts[channel.topic] = counts.get(channel.topic, 0) + 1
                schemas[channel.topic] = (schema.name, schema.encoding, channel.message_encoding)
                if channel.topic == "/camera/image":
                    body = json.loads(message.data)
                    assert body["format"] == "png", body["format"]
        if counts != want:
            print(f"{name}: got {counts}, want {want}", file=sys.stderr)
            bad += 1
        if schemas.get("/camera/image", ("",))[0] != "foxglove.CompressedImage":
            print(f"{name}: image schema {schemas.get('/camera/image')}", file=sys.stderr)
            bad += 1
        print(f"{name}: {json.dumps(counts, sort_keys=True)}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
