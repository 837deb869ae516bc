//! The `bimtiles` binary: a thin shell over the library (see `cli`).

mod cli;

fn main() {
    if let Err(e) = cli::main() {
        // One line, naming the file and the problem; the chain adds context where there is some.
        let mut msg = format!("error: {e}");
        for cause in e.chain().skip(1) {
            msg.push_str(&format!(": {cause}"));
        }
        eprintln!("{msg}");
        std::process::exit(1);
    }
}
