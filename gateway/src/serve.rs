//! `gateway serve --config BOX.toml`: the service until SIGTERM or SIGINT.

use anyhow::Context;
use std::path::Path;
use std::process::ExitCode;

pub fn serve(config_path: &Path) -> anyhow::Result<ExitCode> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        // Under systemd (or any pipe) plain text: colour codes would litter the journal.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let config = service::BoxConfig::load(config_path)?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    rt.block_on(async {
        let running = service::start(config).await?;
        eprintln!(
            "gateway service on {} (token in the token file)",
            running.url()
        );
        if let Some(tls) = running.tls() {
            // What the operator compares with the browser's certificate viewer.
            eprintln!(
                "certificate {} SHA-256 {}",
                tls.cert_file.display(),
                tls.cert_sha256
            );
        }
        wait_for_stop_signal().await?;
        tracing::info!("stop signal: stopping running jobs safely");
        running.shutdown().await;
        anyhow::Ok(())
    })?;
    Ok(ExitCode::SUCCESS)
}

#[cfg(unix)]
async fn wait_for_stop_signal() -> anyhow::Result<()> {
    use tokio::signal::unix::{signal, SignalKind};
    let mut term = signal(SignalKind::terminate()).context("SIGTERM handler")?;
    let mut int = signal(SignalKind::interrupt()).context("SIGINT handler")?;
    tokio::select! {
        _ = term.recv() => {}
        _ = int.recv() => {}
    }
    Ok(())
}

#[cfg(not(unix))]
async fn wait_for_stop_signal() -> anyhow::Result<()> {
    tokio::signal::ctrl_c().await.context("Ctrl-C handler")
}
