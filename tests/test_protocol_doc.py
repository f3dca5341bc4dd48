"""docs/protocol.md is generated from the key table and schemas: it must be current."""
from pathlib import Path

from fabric.protocol_doc import render
from fabric.schemas import REGISTRY
from fabric.wire.keys import ENDPOINTS, TOPICS

DOC = Path(__file__).resolve().parents[1] / "docs" / "protocol.md"


def test_protocol_doc_is_current():
    assert DOC.read_text() == render(), "run: python -m fabric.protocol_doc > docs/protocol.md"


def test_protocol_doc_names_every_key_and_message():
    text = DOC.read_text()
    for service, command in ENDPOINTS:
        assert f"am/<cell>/{service}/cmd/{command}" in text
    for service, topic in TOPICS:
        assert f"am/<cell>/{service}/{topic}" in text
    for name in REGISTRY:
        assert f"### `{name}`" in text
