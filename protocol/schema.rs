//! The schema of `src/messages.rs` as canonical text, and its hash.
//!
//! Shared by `build.rs` (which bakes the hash into `SCHEMA_HASH`) and the
//! tests (which check that edits to comments keep it and edits to messages
//! move it). The schema is what decides the bytes on the wire: every struct
//! and enum, in file order, with its name and body (field names and types,
//! variant names and payloads, in order). Comments, doc comments,
//! attributes (derives, `cfg_attr`), visibility, `use` lines, `impl` blocks,
//! constants and functions are not part of it, nor is layout or a trailing
//! comma. Written without a parser crate so the protocol keeps no build
//! dependencies; `src/messages.rs` holds only plain items.

use std::string::String;
use std::vec::Vec;

/// FNV-1a (32 bit) of `bytes`.
pub fn fnv1a(bytes: &[u8]) -> u32 {
    let mut h: u32 = 0x811c_9dc5;
    for &b in bytes {
        h ^= b as u32;
        h = h.wrapping_mul(0x0100_0193);
    }
    h
}

/// The hash the host and the MCU compare on connect.
pub fn schema_hash(source: &str) -> u32 {
    fnv1a(schema_text(source).as_bytes())
}

/// One line per struct or enum: `struct Name { field : Type , ... }`,
/// tokens separated by one space.
pub fn schema_text(source: &str) -> String {
    let tokens = tokenize(source);
    let mut out = String::new();
    let mut i = 0;
    while i < tokens.len() {
        match tokens[i].as_str() {
            "#" => i = skip_attribute(&tokens, i),
            "pub" => i = skip_visibility(&tokens, i),
            kind @ ("struct" | "enum") => {
                let start = i;
                let end = item_end(&tokens, i);
                let body = clean(&tokens[start + 1..end]);
                out.push_str(kind);
                for t in body {
                    out.push(' ');
                    out.push_str(t);
                }
                out.push('\n');
                i = end;
            }
            // use, impl, const, fn, mod, type...: not schema.
            _ => i = item_end(&tokens, i),
        }
    }
    out
}

/// Identifiers, numbers, string literals, `::` and single punctuation
/// characters; comments and whitespace dropped.
fn tokenize(source: &str) -> Vec<String> {
    let b = source.as_bytes();
    let mut tokens = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        if c.is_ascii_whitespace() {
            i += 1;
        } else if b[i..].starts_with(b"//") {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i..].starts_with(b"/*") {
            let mut depth = 0;
            while i < b.len() {
                if b[i..].starts_with(b"/*") {
                    depth += 1;
                    i += 2;
                } else if b[i..].starts_with(b"*/") {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if c == b'"' {
            let start = i;
            i += 1;
            while i < b.len() && b[i] != b'"' {
                i += if b[i] == b'\\' { 2 } else { 1 };
            }
            i = (i + 1).min(b.len());
            tokens.push(source[start..i].into());
        } else if c.is_ascii_alphanumeric() || c == b'_' {
            let start = i;
            while i < b.len() && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
                i += 1;
            }
            tokens.push(source[start..i].into());
        } else if b[i..].starts_with(b"::") {
            tokens.push("::".into());
            i += 2;
        } else {
            // Multi-byte UTF-8 only appears in comments and strings.
            let len = source[i..].chars().next().map_or(1, char::len_utf8);
            tokens.push(source[i..i + len].into());
            i += len;
        }
    }
    tokens
}

/// Index after the bracket group that starts at `open`.
fn group_end(tokens: &[String], open: usize) -> usize {
    let mut depth = 0i32;
    let mut i = open;
    while i < tokens.len() {
        match tokens[i].as_str() {
            "(" | "[" | "{" => depth += 1,
            ")" | "]" | "}" => {
                depth -= 1;
                if depth <= 0 {
                    return i + 1;
                }
            }
            _ => {}
        }
        i += 1;
    }
    tokens.len()
}

/// `#[...]` or `#![...]` starting at `i`: the index after it.
fn skip_attribute(tokens: &[String], i: usize) -> usize {
    let mut j = i + 1;
    if tokens.get(j).is_some_and(|t| t == "!") {
        j += 1;
    }
    if tokens.get(j).is_some_and(|t| t == "[") {
        group_end(tokens, j)
    } else {
        j
    }
}

/// `pub` or `pub(...)` starting at `i`: the index after it.
fn skip_visibility(tokens: &[String], i: usize) -> usize {
    if tokens.get(i + 1).is_some_and(|t| t == "(") {
        group_end(tokens, i + 1)
    } else {
        i + 1
    }
}

/// The end of the item starting at `i`: after its `;` at depth 0, or after
/// its brace group (and a `;` right after a tuple struct's parentheses).
fn item_end(tokens: &[String], i: usize) -> usize {
    let mut j = i;
    while j < tokens.len() {
        match tokens[j].as_str() {
            ";" => return j + 1,
            "{" => return group_end(tokens, j),
            "(" | "[" => j = group_end(tokens, j),
            _ => j += 1,
        }
    }
    tokens.len()
}

/// An item's tokens without attributes, visibility or trailing commas.
fn clean(tokens: &[String]) -> Vec<&str> {
    let mut out: Vec<&str> = Vec::new();
    let mut i = 0;
    while i < tokens.len() {
        match tokens[i].as_str() {
            "#" => i = skip_attribute(tokens, i),
            "pub" => i = skip_visibility(tokens, i),
            t @ ("}" | ")" | "]" | ">") => {
                if out.last() == Some(&",") {
                    out.pop();
                }
                out.push(t);
                i += 1;
            }
            t => {
                out.push(t);
                i += 1;
            }
        }
    }
    out
}
