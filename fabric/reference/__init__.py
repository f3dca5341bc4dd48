"""The protocol reference's sources beside the code: field descriptions read from the schemas' comments, the
station's events, the rates, the prose and a worked example per command. ``fabric.protocol_doc`` renders them
(docs/protocol.md) and ``fabric.reference.jsonschema`` describes the same for machines (docs/protocol.json)."""
