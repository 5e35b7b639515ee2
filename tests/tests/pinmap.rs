//! The pin map in `hardware::PIN_MAP` and the board layer in
//! `firmware/src/board.rs` agree: every signal is claimed on its pin, no pin
//! is claimed for another signal, and the board claims no pin the map lacks.
//!
//! Convention in board.rs: a line that takes a pin names it as `p.PXn` and
//! its signal as `// Signal::Name` (or `Signal::Lamp(3)`) on the same line.

use hardware::PIN_MAP;
use std::collections::BTreeMap;

const BOARD_RS: &str = include_str!("../../firmware/src/board.rs");

/// STM32 pin names taken from the peripherals on one line of code (`p.PA8`).
fn pins_in(code: &str) -> Vec<&str> {
    code.match_indices("p.P")
        .filter_map(|(i, _)| {
            let rest = &code[i + 2..];
            let end = rest
                .find(|c: char| !c.is_ascii_alphanumeric())
                .unwrap_or(rest.len());
            let pin = &rest[..end];
            let ok = pin.len() >= 3
                && pin.as_bytes()[1].is_ascii_uppercase()
                && pin[2..].bytes().all(|b| b.is_ascii_digit());
            ok.then_some(pin)
        })
        .collect()
}

/// Every disagreement between a board source and `PIN_MAP`.
fn check(board_src: &str) -> Vec<String> {
    let mut problems = Vec::new();
    // signal -> (pin, line)
    let mut claims: BTreeMap<String, Vec<(String, usize)>> = BTreeMap::new();
    let mut pin_owner: BTreeMap<String, String> = BTreeMap::new();
    for (n, line) in board_src.lines().enumerate() {
        let n = n + 1;
        if line.trim_start().starts_with("//") {
            continue;
        }
        let (code, signal) = match line.find("// Signal::") {
            Some(at) => (
                &line[..at],
                Some(line[at + "// Signal::".len()..].trim().to_string()),
            ),
            None => (line.split("//").next().unwrap_or(""), None),
        };
        let pins = pins_in(code);
        match (signal, pins.as_slice()) {
            (None, []) => {}
            (None, _) => {
                problems.push(format!("line {n}: {pins:?} taken without a Signal comment"))
            }
            (Some(s), [pin]) => {
                if let Some(prev) = pin_owner.insert(pin.to_string(), s.clone()) {
                    problems.push(format!("line {n}: {pin} claimed for both {prev} and {s}"));
                }
                claims.entry(s).or_default().push((pin.to_string(), n));
            }
            (Some(s), _) => problems.push(format!(
                "line {n}: Signal::{s} needs exactly one pin on its line, found {pins:?}"
            )),
        }
    }
    for a in PIN_MAP {
        let want = format!("{:?}", a.signal);
        match claims.remove(&want).as_deref() {
            None => problems.push(format!(
                "Signal::{want} ({}) is not claimed in board.rs",
                a.pin
            )),
            Some([(pin, n)]) if pin == a.pin => {}
            Some([(pin, n)]) => problems.push(format!(
                "line {n}: Signal::{want} on {pin}, hardware::PIN_MAP says {}",
                a.pin
            )),
            Some(many) => problems.push(format!("Signal::{want} claimed several times: {many:?}")),
        }
    }
    for (s, at) in claims {
        problems.push(format!("Signal::{s} at {at:?} is not in hardware::PIN_MAP"));
    }
    problems
}

#[test]
fn board_and_pin_map_agree() {
    let problems = check(BOARD_RS);
    assert!(
        problems.is_empty(),
        "pin map disagreements:\n{}",
        problems.join("\n")
    );
}

#[test]
fn swapped_pins_are_caught() {
    let swapped = BOARD_RS
        .replace("p.PA8,", "p.PTMP0,")
        .replace("p.PB5,", "p.PA8,")
        .replace("p.PTMP0,", "p.PB5,");
    assert_ne!(swapped, BOARD_RS, "fixture no longer matches board.rs");
    let problems = check(&swapped);
    assert_eq!(problems.len(), 2, "{problems:?}");
    assert!(problems.iter().any(|p| p.contains("TurntableStep on PB5")));
}

#[test]
fn missing_and_unknown_claims_are_caught() {
    let missing = BOARD_RS.replace("// Signal::Lamp(7)", "");
    let problems = check(&missing);
    assert!(
        problems
            .iter()
            .any(|p| p.contains("without a Signal comment")),
        "{problems:?}"
    );
    assert!(
        problems
            .iter()
            .any(|p| p.contains("Signal::Lamp(7) (PB2) is not claimed"))
    );
    let unknown = BOARD_RS.replace("// Signal::Lamp(7)", "// Signal::Lamp(8)");
    assert!(check(&unknown).iter().any(|p| p.contains("Lamp(8)")));
}

#[test]
fn wiring_table_matches_the_pin_map() {
    let wiring = include_str!("../../hardware/WIRING.md");
    for a in PIN_MAP {
        let row = format!("| {:?} | {} | {} |", a.signal, a.pin, a.header);
        assert!(
            wiring.lines().any(|l| l.starts_with(&row)),
            "hardware/WIRING.md lacks the row `{row} ...`"
        );
    }
    let rows = wiring
        .lines()
        .filter(|l| {
            let cells: Vec<_> = l.split('|').map(str::trim).collect();
            cells.len() > 3
                && cells[2].starts_with('P')
                && cells[2][1..2].chars().all(|c| c.is_ascii_uppercase())
                && cells[2].len() <= 4
        })
        .count();
    assert_eq!(rows, PIN_MAP.len(), "WIRING.md has pin rows the map lacks");
}
