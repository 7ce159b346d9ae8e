//! Conformance harnesses: each protocol document's state table as data, and a driver that takes a device through every cell of it over the protocol itself.
//!
//! The simulators are the reference devices (sim/tests/conformance_*.rs run every cell
//! against them); a device built from docs/modbus.md, docs/sewing-link.md or docs/grbl.md
//! can be driven through the same cells. Each table renders as the markdown the document
//! carries, and a test checks that the document holds exactly that table.

pub mod grbl;
pub mod modbus;
pub mod sewing;

/// One cell of a state table: what the device answers and the state after it (`None`: the
/// state stays).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Cell<A, C> {
    pub answer: A,
    pub next: Option<C>,
}

/// A cell.
pub fn cell_of<A, C>(answer: A, next: Option<C>) -> Cell<A, C> {
    Cell { answer, next }
}

/// A state table as markdown: one row per request (`ask` names it), one column per state
/// (`column` names it), `cell` the text of each cell.
pub fn markdown<A: Copy, C: Copy>(
    corner: &str,
    asks: &[A],
    columns: &[C],
    ask: impl Fn(A) -> String,
    column: impl Fn(C) -> String,
    cell: impl Fn(A, C) -> String,
) -> String {
    let heads: Vec<String> = columns.iter().map(|c| column(*c)).collect();
    let mut s = format!("| {corner} | {} |\n", heads.join(" | "));
    s.push_str(&format!("|---|{}\n", "---|".repeat(columns.len())));
    for a in asks {
        let cells: Vec<String> = columns.iter().map(|c| cell(*a, *c)).collect();
        s.push_str(&format!("| {} | {} |\n", ask(*a), cells.join(" | ")));
    }
    s
}

/// Checks one row: `check` runs the cell of each column on a fresh device; every failure
/// is collected (one never hides another) and the test fails naming each cell.
pub async fn every_column<C, F, Fut>(columns: &[C], row: &str, mut check: F)
where
    C: Copy + std::fmt::Debug,
    F: FnMut(C) -> Fut,
    Fut: std::future::Future<Output = Result<(), String>>,
{
    let mut failures = Vec::new();
    for c in columns {
        if let Err(e) = check(*c).await {
            failures.push(format!("{c:?} × {row}: {e}"));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// One test per row of a state table: `conformance_rows!(row_fn, ASKS; name => ask, …)`
/// defines an async test per row that awaits `row_fn(ask)`, and a test that the rows named
/// are the table's rows, all of them, in order.
#[macro_export]
macro_rules! conformance_rows {
    ($row:ident, $all:expr; $($name:ident => $ask:expr),* $(,)?) => {
        $(
            #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
            async fn $name() {
                $row($ask).await;
            }
        )*

        #[test]
        fn every_row_of_the_table_has_its_test() {
            assert_eq!([$($ask),*].to_vec(), $all.to_vec());
        }
    };
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
