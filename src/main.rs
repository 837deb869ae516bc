//! The `bimtiles` binary: a thin shell over the library (see `cli`). Every failure ends as one
//! `error:` line and exit code 1, a panic too (ours or a dependency's, on any thread): the panic
//! hook only records it, and the details are printed when `RUST_BACKTRACE` is set.

mod cli;

use std::sync::Mutex;

/// The first panic of the process: its message and where it happened.
static PANIC: Mutex<Option<String>> = Mutex::new(None);

fn main() {
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let message = bimtiles::error::panic_message(info.payload());
        let place = info
            .location()
            .map(|l| format!(" at {}:{}", l.file(), l.line()))
            .unwrap_or_default();
        let mut first = PANIC.lock().unwrap_or_else(|p| p.into_inner());
        first.get_or_insert(format!("{message}{place}"));
        if std::env::var_os("RUST_BACKTRACE").is_some_and(|v| v != "0") {
            default_hook(info);
        }
    }));
    let result = std::panic::catch_unwind(|| {
        // Test hook: a panic in a worker thread, for the test of this one-line rule.
        if std::env::var_os("BIMTILES_TEST_PANIC").is_some() {
            rayon::join(|| (), || panic!("BIMTILES_TEST_PANIC is set"));
        }
        cli::main()
    });
    let msg = match result {
        Ok(Ok(())) => return,
        Ok(Err(e)) => {
            // One line, naming the file and the problem; the chain adds context where there is
            // some.
            let mut msg = format!("error: {e}");
            for cause in e.chain().skip(1) {
                msg.push_str(&format!(": {cause}"));
            }
            msg
        }
        Err(_) => {
            let what = PANIC
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .clone()
                .unwrap_or_else(|| "unknown panic".into());
            let inputs = input_files_named();
            format!(
                "error: {}internal error (a bug in bimtiles or a library it uses): {what}; run with RUST_BACKTRACE=1 for details",
                match inputs.is_empty() {
                    true => String::new(),
                    false => format!("{}: ", inputs.join(", ")),
                }
            )
        }
    };
    eprintln!("{msg}");
    std::process::exit(1);
}

/// The command line's arguments that name existing files (the inputs), for a panic's message.
fn input_files_named() -> Vec<String> {
    std::env::args()
        .skip(2)
        .filter(|a| !a.starts_with('-') && std::path::Path::new(a).is_file())
        .collect()
}
