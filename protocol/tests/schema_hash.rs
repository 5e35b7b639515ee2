//! `SCHEMA_HASH` follows the message schema, not the text of messages.rs: a
//! documentation edit keeps it (flashed rigs keep talking to a new host),
//! a change to a name, a field, a type or their order moves it.

#[path = "../schema.rs"]
mod schema;

use schema::{schema_hash, schema_text};

const MESSAGES: &str = include_str!("../src/messages.rs");

fn edited(from: &str, to: &str) -> String {
    assert!(
        MESSAGES.contains(from),
        "messages.rs no longer has {from:?}"
    );
    MESSAGES.replacen(from, to, 1)
}

#[test]
fn the_baked_hash_is_the_hash_of_the_schema() {
    assert_eq!(schema_hash(MESSAGES), protocol::SCHEMA_HASH);
    assert_eq!(schema_text(MESSAGES), protocol::SCHEMA_TEXT);
    let text = protocol::SCHEMA_TEXT;
    // Every message type, in file order, and nothing that is not schema.
    assert!(
        text.starts_with("struct HostFrame { seq : u16 , command : Command }\n"),
        "{text}"
    );
    assert!(
        text.contains("enum Axis { Turntable , LightArc }\n"),
        "{text}"
    );
    assert!(text.contains("board : heapless :: String < 24 >"), "{text}");
    assert_eq!(text.lines().count(), 16, "{text}");
    for not_schema in [
        "///", "//", "derive", "cfg_attr", "pub", "impl", "ALL", "index",
    ] {
        assert!(
            !text.contains(not_schema),
            "{not_schema:?} in the schema:\n{text}"
        );
    }
}

#[test]
fn comments_attributes_and_layout_keep_the_hash() {
    let h = schema_hash(MESSAGES);
    let keep = [
        edited(
            "/// Handshake: answered with `Reply::Identity`. Restarts the sequence.",
            "/// Says hello. (Rewritten documentation, /* even */ with \"quotes\".)",
        ),
        edited(
            "pub seq: u16,",
            "// a new comment line\n    pub seq: u16, /* and a block */",
        ),
        edited(
            "pub enum Axis {",
            "/* a block comment\n   over lines */\npub enum Axis {",
        ),
        edited(
            "    Turntable,\n    LightArc,\n}",
            "    Turntable, LightArc\n}",
        ),
        edited(
            "#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]\n#[cfg_attr(feature = \"defmt\", derive(defmt::Format))]\npub enum Axis",
            "#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]\npub enum Axis",
        ),
        edited(
            "impl Axis {",
            "impl Axis {\n    pub const COUNT: usize = 2;",
        ),
        format!("{MESSAGES}\n/// A helper.\npub const fn answer() -> u32 {{ 42 }}\n"),
    ];
    for (i, src) in keep.iter().enumerate() {
        assert_eq!(schema_hash(src), h, "edit {i} moved the hash");
    }
}

#[test]
fn changes_to_messages_move_the_hash() {
    let h = schema_hash(MESSAGES);
    let moved = [
        ("a field type", edited("pub seq: u16,", "pub seq: u32,")),
        (
            "a field name",
            edited("Heartbeat { event_ack: u16 }", "Heartbeat { ack: u16 }"),
        ),
        (
            "field order",
            edited(
                "    pub seq: u16,\n    pub command: Command,",
                "    pub command: Command,\n    pub seq: u16,",
            ),
        ),
        ("a variant name", edited("    LightArc,\n}", "    Arc,\n}")),
        (
            "a new variant",
            edited("    Reset,\n}", "    Reset,\n    PowerOff,\n}"),
        ),
        (
            "a type name",
            edited("pub struct Limits {", "pub struct Limit {"),
        ),
        (
            "an array length",
            edited(
                "pub board: heapless::String<24>,",
                "pub board: heapless::String<32>,",
            ),
        ),
        ("a payload type", edited("Absolute(i32),", "Absolute(i64),")),
    ];
    for (what, src) in &moved {
        assert_ne!(schema_hash(src), h, "{what} kept the hash");
    }
}
