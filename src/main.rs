use clap::Parser;

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
