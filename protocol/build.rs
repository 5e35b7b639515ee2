//! Bakes the message schema's hash into the crate (`SCHEMA_HASH`): the hash
//! of the struct and enum definitions in `src/messages.rs`, not of its text,
//! so comments can change without making flashed rigs refuse the host.

#[path = "schema.rs"]
mod schema;

use std::path::PathBuf;

fn main() {
    println!("cargo:rerun-if-changed=src/messages.rs");
    println!("cargo:rerun-if-changed=schema.rs");
    let source = std::fs::read_to_string("src/messages.rs").expect("read src/messages.rs");
    let text = schema::schema_text(&source);
    let hash = schema::schema_hash(&source);
    let out = PathBuf::from(std::env::var_os("OUT_DIR").expect("OUT_DIR set by cargo"));
    let code = format!(
        "/// FNV-1a (32 bit) of [`SCHEMA_TEXT`].\n\
         pub const SCHEMA_HASH: u32 = {hash:#010x};\n\
         /// The message schema as canonical text: one line per struct or enum\n\
         /// of `messages.rs` (names, fields, types, variants, in order).\n\
         pub const SCHEMA_TEXT: &str = {text:?};\n"
    );
    std::fs::write(out.join("schema_hash.rs"), code).expect("write schema_hash.rs");
}
