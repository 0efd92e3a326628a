"""Reads an asbuilt recording with the reference Python MCAP reader and prints what it holds:
message counts per topic, schema names, attachments and metadata names. Exits non-zero if the
file does not read."""

import sys
from collections import Counter

from mcap.reader import make_reader


def main(path: str) -> None:
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, "no summary section"
        counts = Counter()
        for schema, channel, message in reader.iter_messages():
            assert channel.message_encoding == "asbuilt-postcard", channel.message_encoding
            assert schema.name.startswith("asbuilt."), schema.name
            assert len(schema.data) > 0
            counts[channel.topic] += 1
        for topic, n in sorted(counts.items()):
            print(topic, n)
        for a in reader.iter_attachments():
            print("attachment", a.name, len(a.data) // 1000)
        for m in reader.iter_metadata():
            print("metadata", m.name, sorted(m.metadata))


if __name__ == "__main__":
    main(sys.argv[1])
