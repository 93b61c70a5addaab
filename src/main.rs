use clap::Parser;

// Until the first subcommand lands, `Command` is empty (uninhabited), so rustc sees the code after
// `parse()` as unreachable. Remove this allow then.
#[allow(unreachable_code, unused_variables)]
fn main() -> std::process::ExitCode {
    let cli = densefeat::cli::Cli::parse();
    match densefeat::cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
