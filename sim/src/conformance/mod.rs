//! Conformance harnesses: each protocol document's state table as data, and a driver that takes a device through every cell of it over the protocol itself.
//!
//! The simulators are the reference devices (sim/tests/conformance_*.rs run every cell
//! against them); a device built from docs/modbus.md, docs/sewing-link.md or docs/grbl.md
//! can be driven through the same cells. Each table renders as the markdown the document
//! carries, and a test checks that the document holds exactly that table.

pub mod grbl;
pub mod modbus;
pub mod sewing;

/// A state table as markdown: one row per request, one column per state.
pub fn markdown(corner: &str, states: &[&str], rows: &[(String, Vec<String>)]) -> String {
    let mut s = format!("| {corner} | {} |\n", states.join(" | "));
    s.push_str(&format!("|---|{}\n", "---|".repeat(states.len())));
    for (request, cells) in rows {
        s.push_str(&format!("| {request} | {} |\n", cells.join(" | ")));
    }
    s
}

/// Checks that `doc` (a file under docs/) holds `table` verbatim; the error shows the table
/// to paste.
pub fn document_holds(doc: &str, table: &str) -> Result<(), String> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../docs")
        .join(doc);
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    if text.contains(table) {
        Ok(())
    } else {
        Err(format!(
            "docs/{doc} does not hold the state table the conformance test runs; it should read:\n\n{table}"
        ))
    }
}
