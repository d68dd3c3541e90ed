//! The README's table of what each configuration costs and scores is generated from
//! `docs/results/configurations.csv` (cells of `ctadsa experiment`): this test fails, printing the
//! table to paste, when the README and the file disagree.

use std::path::Path;

use ctadsa_core::run::results::{configurations_table, parse_results_csv};

const START: &str = "<!-- configurations table: generated from docs/results/configurations.csv by tests/readme.rs -->";
const END: &str = "<!-- end of configurations table -->";

#[test]
fn the_readme_table_is_the_one_the_results_give() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let csv_path = root.join("docs/results/configurations.csv");
    let csv = std::fs::read_to_string(&csv_path).expect("docs/results/configurations.csv");
    let results = parse_results_csv(&csv, &csv_path).expect("a results.csv of ctadsa experiment");
    assert!(!results.is_empty(), "no cells in {}", csv_path.display());
    let table = configurations_table(&results);
    let readme = std::fs::read_to_string(root.join("README.md")).expect("README.md");
    let start = readme.find(START).expect("the README marks where its table starts") + START.len();
    let end = readme[start..].find(END).expect("the README marks where its table ends") + start;
    assert_eq!(
        readme[start..end].trim(),
        table.trim(),
        "README.md's table differs from the one docs/results/configurations.csv gives; put this between \
         the markers:\n\n{table}"
    );
}
