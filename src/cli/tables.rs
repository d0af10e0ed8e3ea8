//! The tables the run commands print (built in the library, which `report.html` shares).

use evitrack::report::tables::{confidence_table, error_table, fault_table};
pub(super) use evitrack::report::tables::{evidential_of, seed_tables, states_text};
use evitrack::report::RunSummary;

/// Prints the error table, the fault table when runs had faults, the confidence table, and a
/// line for each run whose test frames lie mostly beyond its calibration motion's reach.
pub(super) fn print_tables(summaries: &[&RunSummary]) {
    println!("{}", error_table(summaries));
    if let Some(faults) = fault_table(summaries) {
        println!("{faults}");
    }
    if let Some(confidence) = confidence_table(summaries) {
        println!("{confidence}");
    }
    let reach = (summaries.iter()).filter_map(|s| s.calibration_reach.as_ref()?.note(&s.scenario));
    for line in reach {
        println!("{line}");
    }
}
