//! The `densefeat` command-line tool: flags parsed here (`cli`), the work done by the library.

mod cli;

use clap::Parser;

fn main() -> std::process::ExitCode {
    // Freed activation maps are reused rather than returned to the OS (SPEC.md §8.9).
    densefeat::runtime::keep_freed_memory();
    let cli = cli::Cli::parse();
    match cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
