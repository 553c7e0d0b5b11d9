//! What the `voxserve` subcommands do (their flags are in [`crate::cli`]).

use std::io::Write as _;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use blocks::Geometry;
use blocks::ingest::dicom::{FolderScan, SeriesSummary};
use blocks::ingest::{self, VolumeInfo, VolumeSource, VolumeStats};

use tokio::net::TcpListener;

use crate::cli::{
    AuthArgs, Command, DataArgs, InfoArgs, IngestArgs, PacsArgs, PacsCommand, PacsFetchArgs,
    PacsLinkArgs, RenderArgs, ServeArgs, SettingsArgs, TokenArgs, VerifyArgs,
};
use crate::dataset::PHANTOM_ID;
use crate::{AppState, Dataset, RenderService, encode};

/// Runs one of the server's subcommands.
pub fn run(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Serve(args) => tokio::runtime::Runtime::new()
            .map_err(anyhow::Error::from)
            .and_then(|rt| rt.block_on(serve(*args))),
        Command::Render(args) => render(*args),
        Command::Info(args) => info(&args),
        Command::Ingest(args) => ingest(&args),
        Command::Verify(args) => verify(&args),
        Command::Settings(args) => settings(&args),
        Command::Token(args) => token(args),
        Command::Pacs(command) => tokio::runtime::Runtime::new()
            .map_err(anyhow::Error::from)
            .and_then(|rt| rt.block_on(pacs(command))),
    }
}

/// The PACS client `args` configure.
pub fn dicomweb(args: &PacsArgs) -> anyhow::Result<crate::pacs::DicomWeb> {
    let link = &args.link;
    if link.pacs.is_empty() {
        anyhow::bail!("--pacs: expected at least one NAME=URL, the PACS to ask");
    }
    let endpoints = crate::pacs::Endpoints::new(link.pacs.clone(), &link.auth)?;
    let endpoint = endpoints.pick(args.from.as_deref())?.clone();
    crate::pacs::DicomWeb::new(endpoint, std::time::Duration::from_secs(link.timeout_s))
}

/// A client of every PACS `args` names.
fn dicomwebs(args: &PacsLinkArgs) -> anyhow::Result<Vec<crate::pacs::DicomWeb>> {
    let endpoints = crate::pacs::Endpoints::new(args.pacs.clone(), &args.auth)?;
    endpoints
        .all()
        .iter()
        .map(|e| {
            crate::pacs::DicomWeb::new(e.clone(), std::time::Duration::from_secs(args.timeout_s))
        })
        .collect()
}

/// `voxserve pacs search | series | fetch`.
pub async fn pacs(command: PacsCommand) -> anyhow::Result<()> {
    match command {
        PacsCommand::Search(args) => {
            let web = dicomweb(&args.pacs)?;
            let query = crate::pacs::StudyQuery {
                patient_name: args.patient_name,
                patient_id: args.patient_id,
                accession_number: args.accession,
                study_date: args.study_date,
                modality: args.modality,
                study_uid: args.study,
                limit: args.limit,
                offset: args.offset,
            };
            query.check().map_err(anyhow::Error::msg)?;
            for study in web.search_studies(&query).await? {
                if args.json {
                    say(&serde_json::to_string(&study)?)?;
                    continue;
                }
                let or = |v: &Option<String>| v.clone().unwrap_or_else(|| "-".into());
                say(&format!(
                    "{}  {}  {}  \"{}\"  {}  {} series, {} images  \"{}\"",
                    study.study_uid,
                    or(&study.study_date),
                    or(&study.patient_id),
                    or(&study.patient_name),
                    study.modalities.join("/"),
                    study.series.map_or("?".into(), |n| n.to_string()),
                    study.instances.map_or("?".into(), |n| n.to_string()),
                    or(&study.description),
                ))?;
            }
            Ok(())
        }
        PacsCommand::Series(args) => {
            let web = dicomweb(&args.pacs)?;
            for series in web.search_series(&args.study).await? {
                if args.json {
                    say(&serde_json::to_string(&series)?)?;
                    continue;
                }
                say(&format!(
                    "{}  {}  #{}  {} images  \"{}\"",
                    series.series_uid,
                    series.modality.as_deref().unwrap_or("?"),
                    series.number.map_or("?".into(), |n| n.to_string()),
                    series.instances.map_or("?".into(), |n| n.to_string()),
                    series.description.as_deref().unwrap_or(""),
                ))?;
            }
            Ok(())
        }
        PacsCommand::Fetch(args) => pacs_fetch(args).await,
    }
}

/// `voxserve pacs fetch`: a series' instances into a spool folder beside
/// the store, then bricked from there (in bounded memory, as `ingest`).
async fn pacs_fetch(args: PacsFetchArgs) -> anyhow::Result<()> {
    let web = dicomweb(&args.pacs)?;
    let series = match args.series {
        Some(series) => series,
        None => {
            let all = web.search_series(&args.study).await?;
            match all.as_slice() {
                [only] => only.series_uid.clone(),
                [] => anyhow::bail!(
                    "study {}: no series on PACS {}; expected a study it holds (voxserve pacs search lists them)",
                    args.study,
                    web.name()
                ),
                _ => anyhow::bail!(
                    "study {}: {} series; say which with --series:\n{}",
                    args.study,
                    all.len(),
                    all.iter()
                        .map(|s| format!(
                            "  {}  {} {} images  {}",
                            s.series_uid,
                            s.modality.as_deref().unwrap_or("?"),
                            s.instances.map_or("?".into(), |n| n.to_string()),
                            s.description.as_deref().unwrap_or("")
                        ))
                        .collect::<Vec<_>>()
                        .join("\n")
                ),
            }
        }
    };
    let spool_in = match args.out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&spool_in)
        .with_context(|| format!("{}: cannot make the folder", spool_in.display()))?;
    let options = crate::pacs::fetch::FetchOptions {
        concurrency: usize::from(args.concurrency),
        max_instance_bytes: args.max_instance_mib << 20,
        ..Default::default()
    };
    let bar = progress_bar(0, "fetching");
    let progress = |done: usize, total: usize, _bytes: u64| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    };
    let fetched =
        crate::pacs::fetch::fetch_series(&web, &args.study, &series, &spool_in, options, &progress)
            .await?;
    bar.finish_and_clear();
    say(&format!(
        "fetched series {series} of study {}: {} instance(s), {:.1} MB in {:.1} s ({:.0} MB/s, {:.0} instances/s)",
        args.study,
        fetched.instances.len(),
        fetched.bytes as f64 / 1e6,
        fetched.seconds,
        fetched.bytes as f64 / 1e6 / fetched.seconds.max(1e-9),
        fetched.instances.len() as f64 / fetched.seconds.max(1e-9),
    ))?;
    let (out, force, level) = (args.out, args.force, args.zstd_level);
    let what = format!(
        "series {series} of study {} from PACS {}",
        args.study,
        web.name()
    );
    tokio::task::spawn_blocking(move || {
        let mut source = crate::pacs::fetch::open_fetched(&fetched)?;
        write_store(source.as_mut(), &out, force, level)
            .with_context(|| what)?
            .say()
    })
    .await?
}

/// `voxserve token`: a new API token on standard output, its entry for the
/// tokens file on standard error.
pub fn token(args: TokenArgs) -> anyhow::Result<()> {
    let (token, entry) = crate::auth::tokens::generate(&args.name, args.roles)
        .map_err(|e| anyhow::anyhow!("no randomness for a token: {e}"))?;
    let mut err = std::io::stderr().lock();
    writeln!(
        err,
        "add this entry to the \"tokens\" list of the file serve --api-tokens reads:\n{}",
        serde_json::to_string(&entry)?
    )?;
    say(&token)
}

/// What `serve`'s authentication flags set up: how tokens are checked, who
/// may see what, where accesses are recorded.
async fn auth_of(args: &AuthArgs) -> anyhow::Result<(crate::auth::Auth, crate::audit::Audit)> {
    use crate::auth::oidc::{JwksSource, OidcConfig};
    let oidc = match (&args.oidc_issuer, &args.oidc_audience) {
        (Some(issuer), Some(audience)) => {
            let jwks = match &args.oidc_jwks {
                None => JwksSource::Discovery,
                Some(url) if url.starts_with("https://") || url.starts_with("http://") => {
                    JwksSource::Url(url.clone())
                }
                Some(file) => JwksSource::File(PathBuf::from(file)),
            };
            let config = OidcConfig {
                issuer: issuer.clone(),
                audience: audience.clone(),
                jwks,
                client_id: args.oidc_client_id.clone(),
                scopes: args.oidc_scopes.clone(),
            };
            let patience = std::time::Duration::from_secs(args.oidc_wait_s);
            let oidc = crate::auth::Oidc::connect_waiting(config, patience)
                .await
                .with_context(|| format!("--oidc-issuer {issuer}"))?;
            Some(oidc)
        }
        _ => None,
    };
    let tokens = args
        .api_tokens
        .as_deref()
        .map(crate::auth::ApiTokens::load)
        .transpose()?;
    let policy = args
        .policy
        .as_deref()
        .map(crate::auth::Policy::load)
        .transpose()?;
    let auth = crate::auth::Auth {
        oidc,
        tokens,
        policy,
    };
    if auth.policy.is_some() && !auth.required() {
        anyhow::bail!(
            "--policy: the server has no authentication, so everyone would be anonymous; \
             expected --oidc-issuer or --api-tokens with it"
        );
    }
    let audit = match &args.audit_log {
        Some(path) => crate::audit::Audit::open(path).with_context(|| {
            format!("--audit-log {}: cannot open for appending", path.display())
        })?,
        None => crate::audit::Audit::default(),
    };
    Ok((auth, audit))
}

/// Ctrl-C or `SIGTERM` (an orchestrator, systemd, a deployment script):
/// the first resolves the returned future (the server drains); a second
/// exits at once with status 1, for an operator who will not wait.
fn stop_signals(drain_s: u64) -> anyhow::Result<impl Future<Output = ()>> {
    #[cfg(unix)]
    let mut terminate = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
        .context("cannot listen for SIGTERM")?;
    let (first, drain) = tokio::sync::oneshot::channel::<()>();
    tokio::spawn(async move {
        let mut first = Some(first);
        loop {
            #[cfg(unix)]
            let terminated = terminate.recv();
            #[cfg(not(unix))]
            let terminated = std::future::pending::<Option<()>>();
            tokio::select! {
                interrupted = tokio::signal::ctrl_c() => {
                    if let Err(e) = interrupted {
                        tracing::error!("cannot listen for Ctrl-C: {e}");
                        std::future::pending::<()>().await;
                    }
                }
                _ = terminated => {}
            }
            if let Some(first) = first.take() {
                tracing::info!(
                    "draining: sessions finish their frames (at most {drain_s} s), then close; \
                     stop again to exit at once"
                );
                let _ = first.send(());
            } else {
                tracing::warn!("stopped again while draining: exiting at once");
                std::process::exit(1);
            }
        }
    });
    Ok(async move {
        let _ = drain.await;
    })
}

/// On `SIGHUP`: reads the TLS certificate again and reopens the audit log.
#[cfg(unix)]
fn reload_on_hangup(state: &AppState) -> anyhow::Result<()> {
    use tokio::signal::unix::{SignalKind, signal};
    let mut hangups = signal(SignalKind::hangup()).context("cannot listen for SIGHUP")?;
    let (tls, audit) = (state.tls.clone(), state.audit.clone());
    tokio::spawn(async move {
        while hangups.recv().await.is_some() {
            if let Some(tls) = &tls {
                match tls.reload() {
                    Ok(()) => tracing::info!("SIGHUP: read the TLS certificate again"),
                    Err(e) => tracing::error!("SIGHUP: keeping the TLS certificate: {e:#}"),
                }
            }
            if let Err(e) = audit.reopen() {
                tracing::error!("SIGHUP: cannot reopen the audit log: {e}");
            }
        }
    });
    Ok(())
}

#[cfg(not(unix))]
fn reload_on_hangup(_state: &AppState) -> anyhow::Result<()> {
    Ok(())
}

/// `voxserve settings`: every view setting, as Markdown tables or JSON.
pub fn settings(args: &SettingsArgs) -> anyhow::Result<()> {
    if args.json {
        say(&serde_json::to_string_pretty(&crate::view::describe(&[]))?)
    } else {
        say(crate::view::settings_tables().trim())
    }
}

/// Loads the dataset named on the command line: the phantom, a brick store, or
/// a volume file or DICOM folder bricked in memory.
pub fn load_dataset(name: &str, data: &DataArgs) -> anyhow::Result<Dataset> {
    let start = Instant::now();
    if name == PHANTOM_ID {
        let dataset = Dataset::phantom(data.phantom_size, data.cache_bytes())?;
        tracing::info!(
            "generated and bricked the {n}³ phantom in {:.0} ms",
            start.elapsed().as_secs_f64() * 1e3,
            n = data.phantom_size
        );
        return Ok(dataset);
    }
    if blocks::store::is_url(name) {
        let store = blocks::store::Store::open_remote(name)?;
        let id = Dataset::id_of(store.location().file("").to_string_lossy().as_ref());
        let dataset = Dataset::new(id, store, data.cache_bytes())?;
        tracing::info!(
            "opened {name} ({:?} voxels) in {:.0} ms",
            dataset.dims(),
            start.elapsed().as_secs_f64() * 1e3
        );
        return Ok(dataset);
    }
    let path = std::path::Path::new(name);
    if !path.exists() {
        anyhow::bail!(
            "dataset '{name}': no such file or folder: expected '{PHANTOM_ID}' (the built-in CT \
             head phantom), a brick store, a volume file or a folder of DICOM files"
        );
    }
    let dataset = Dataset::load(path, &data.input.open_options(), data.cache_bytes())?;
    tracing::info!(
        "opened {} ({:?} voxels) in {:.0} ms",
        path.display(),
        dataset.dims(),
        start.elapsed().as_secs_f64() * 1e3
    );
    Ok(dataset)
}

/// The brick stores directly inside `dir`, by name. Hidden entries are never
/// stores: what an interrupted ingest left there (`.NAME.partial-PID`,
/// `.NAME.old-PID`) is reported, not served.
pub fn stores_in(dir: &std::path::Path) -> anyhow::Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).with_context(|| {
        format!(
            "--data {}: expected a folder of brick stores",
            dir.display()
        )
    })?;
    let mut stores = Vec::new();
    for entry in entries.filter_map(Result::ok) {
        let (path, name) = (entry.path(), entry.file_name());
        let name = name.to_string_lossy();
        if let Some((of, pid)) = blocks::store::ingest::leftover_of(&name) {
            if !blocks::store::ingest::process_runs(pid) {
                tracing::warn!(
                    "{}: left by an ingest of {of} that did not finish (process {pid}); not \
                     served; the next ingest to {of} removes it, or remove it yourself",
                    path.display()
                );
            }
        } else if !name.starts_with('.') && blocks::store::Store::is_store(&path) {
            stores.push(path);
        }
    }
    stores.sort();
    if stores.is_empty() {
        tracing::warn!("--data {}: no brick stores in it", dir.display());
    }
    Ok(stores)
}

/// The brick stores directly under the object-store prefix `url`: its
/// folders holding a manifest, by URL. Hidden folders are never stores.
pub fn remote_stores_in(url: &str) -> anyhow::Result<Vec<String>> {
    let remote = blocks::store::Remote::parse(url)?;
    let mut stores = Vec::new();
    for folder in remote.folders()? {
        let store = remote.child(&folder);
        if folder.starts_with('.') {
            continue;
        }
        let listed = store.get(
            blocks::store::manifest::MANIFEST_KEY,
            blocks::store::manifest::MAX_MANIFEST_BYTES,
        );
        match listed {
            Ok(Some(_)) => stores.push(store.url().to_owned()),
            Ok(None) => {}
            Err(e) => tracing::error!("not serving {}: {e}", store.url()),
        }
    }
    if stores.is_empty() {
        tracing::warn!("--data {url}: no brick stores in it");
    }
    Ok(stores)
}

/// Writes a line to standard output (the command's result, not a log line).
pub fn say(line: &str) -> anyhow::Result<()> {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{line}")?;
    out.flush()?;
    Ok(())
}

/// `voxserve serve`: serves until Ctrl-C.
pub async fn serve(args: ServeArgs) -> anyhow::Result<()> {
    let (auth, audit) = auth_of(&args.auth).await?;
    if !args.addr.ip().is_loopback() && !auth.required() && !args.insecure_allow_anonymous {
        anyhow::bail!(
            "--addr {}: not a loopback address, and voxserve has no authentication configured: \
             anyone who reaches the port would see every dataset. Expected a loopback address \
             (127.0.0.1, ::1), --oidc-issuer or --api-tokens, or --insecure-allow-anonymous \
             behind a proxy that authenticates every request",
            args.addr
        );
    }
    let tls = match (&args.auth.tls_cert, &args.auth.tls_key) {
        (Some(cert), Some(key)) => Some(std::sync::Arc::new(crate::tls::Tls::load(cert, key)?)),
        _ => None,
    };
    let mut datasets = Vec::new();
    for name in &args.datasets {
        datasets.push(load_dataset(name, &args.data)?);
    }
    if let Some(dir) = &args.data_dir {
        let dir_name = dir.to_string_lossy();
        let names: Vec<String> = if blocks::store::is_url(&dir_name) {
            remote_stores_in(&dir_name)?
        } else {
            stores_in(dir)?
                .iter()
                .map(|p| p.to_string_lossy().into_owned())
                .collect()
        };
        for name in names {
            // A store that does not open is left out, named in the log; the
            // others are served.
            match load_dataset(&name, &args.data) {
                Ok(dataset) => datasets.push(dataset),
                Err(e) => tracing::error!("not serving {name}: {e:#}"),
            }
        }
    }
    let receiver = match &args.receive_dir {
        Some(dir) => {
            let receiver = crate::receive::Receiver::new(
                dir,
                std::time::Duration::from_secs(args.receive_settle_s),
                args.data.cache_bytes(),
                args.receive_max_mib << 20,
            )?;
            for path in receiver.stores()? {
                match load_dataset(&path.to_string_lossy(), &args.data) {
                    Ok(dataset) => datasets.push(dataset),
                    Err(e) => tracing::error!("not serving {}: {e:#}", path.display()),
                }
            }
            Some(receiver)
        }
        None => None,
    };
    let studies = match (&args.pacs_cache, args.pacs.pacs.is_empty()) {
        (None, true) => None,
        (None, false) => anyhow::bail!(
            "--pacs without --pacs-cache: name the folder where series opened from the PACS are kept"
        ),
        (Some(_), true) => {
            anyhow::bail!(
                "--pacs-cache without --pacs: name the PACS (NAME=URL) to open studies from"
            )
        }
        (Some(dir), false) => {
            let studies = crate::studies::Studies::new(
                dicomwebs(&args.pacs)?,
                dir,
                args.pacs_cache_mib << 20,
                args.data.cache_bytes(),
            )?;
            for path in studies.stores()? {
                match load_dataset(&path.to_string_lossy(), &args.data) {
                    Ok(dataset) => datasets.push(dataset),
                    Err(e) => tracing::error!("not serving {}: {e:#}", path.display()),
                }
            }
            Some(studies)
        }
    };
    for (i, d) in datasets.iter().enumerate() {
        if datasets[..i].iter().any(|e| e.id == d.id) {
            anyhow::bail!(
                "two datasets have the id '{}': expected each dataset once, with distinct names",
                d.id
            );
        }
    }
    if args.dicom_port.is_some() && args.dicom_allow.is_empty() {
        anyhow::bail!(
            "--dicom-port without --dicom-allow: name the calling AE titles that may store (or * for any)"
        );
    }
    let backend = args.renderer.backend()?;
    let resident = usize::try_from(args.resident_datasets).unwrap_or(usize::MAX);
    let renderer = RenderService::start(backend, args.data.gpu_budget_bytes(), resident)?;
    renderer.set_max_frame_cost(args.max_frame_cost);
    let listener = TcpListener::bind(args.addr)
        .await
        .with_context(|| format!("cannot listen on {}", args.addr))?;
    let mut addr = listener.local_addr()?;
    if addr.ip().is_unspecified() {
        addr.set_ip(std::net::Ipv4Addr::LOCALHOST.into());
    }
    let names: Vec<String> = datasets
        .iter()
        .map(|d| format!("the {} ({:?} voxels)", d.name(), d.dims()))
        .collect();
    let scheme = if tls.is_some() { "https" } else { "http" };
    let dicom = match args.dicom_port {
        Some(port) => {
            let at = SocketAddr::new(args.addr.ip(), port);
            let listener = TcpListener::bind(at)
                .await
                .with_context(|| format!("--dicom-port: cannot listen on {at}"))?;
            let mut at = listener.local_addr()?;
            if at.ip().is_unspecified() {
                at.set_ip(std::net::Ipv4Addr::LOCALHOST.into());
            }
            Some((listener, at))
        }
        None => None,
    };
    let mut access = args.access.access();
    access.frame_ancestors = args.auth.frame_ancestors.clone();
    let mut state = AppState::new(datasets, renderer, args.stream.settings())
        .with_access(access)
        .with_auth(auth, audit)
        .with_notice(args.notice.clone());
    state.drain_timeout = std::time::Duration::from_secs(args.drain_s);
    if let Some(tls) = tls {
        state = state.with_tls(tls);
    }
    let mut dicom_line = String::new();
    if let Some(receiver) = receiver {
        receiver.spawn_settler(state.datasets.clone(), state.shutdown.clone());
        if let Some((listener, at)) = dicom {
            let settings = crate::dimse::DicomSettings {
                ae_title: args.ae_title.clone(),
                callers: args.dicom_allow.clone(),
            };
            crate::dimse::spawn(
                listener,
                settings,
                std::sync::Arc::clone(&receiver),
                std::sync::Arc::clone(&state.audit),
                state.shutdown.clone(),
            );
            dicom_line = format!(" and DICOM as {} at {at}", args.ae_title);
        }
        state.receiver = Some(receiver);
    }
    state.studies = studies;
    reload_on_hangup(&state)?;
    say(&format!(
        "voxserve: serving {} on {} at {scheme}://{addr}/{dicom_line}",
        names.join(", "),
        state.renderer.adapter()
    ))?;
    let shutdown = stop_signals(args.drain_s)?;
    crate::run(listener, state, shutdown).await?;
    Ok(())
}

/// `voxserve render`: one frame to a PNG file.
pub fn render(args: RenderArgs) -> anyhow::Result<()> {
    let dataset = load_dataset(&args.dataset, &args.data)?;
    let out = args
        .out
        .unwrap_or_else(|| PathBuf::from(format!("{}.png", dataset.id)));
    let output = OutputFile::prepare(out)?;
    let request = args.view.frame;
    if let Some(preset) = request.preset {
        dataset
            .check_preset(preset)
            .map_err(|e| anyhow::anyhow!("--{e}"))?;
    }
    let classification = match (&request.tf, request.preset) {
        (Some(_), _) => "its own transfer function".to_owned(),
        (None, preset) => preset
            .unwrap_or_else(|| dataset.default_preset())
            .to_string(),
    };
    let start = Instant::now();
    let backend = args.renderer.backend()?;
    let mut renderer = backend.renderer(dataset.cache.clone(), args.data.gpu_budget_bytes())?;
    // A still image: the light with every in-scattering direction in.
    let frame = renderer.render_converged(&request)?;
    let stats = renderer.last_stats();
    if let Some(light) = stats.light() {
        tracing::info!(
            "light: local_opacity {:.0} ms, global_opacity {:.0} ms, direct_light {:.0} ms, \
             in_scatter {:.0} ms ({} directions)",
            light.local_opacity_ms,
            light.global_opacity_ms,
            light.direct_light_ms,
            light.in_scatter_ms,
            light.directions
        );
    }
    if let Some(camera) = &stats.camera {
        // The fit's camera as flags, to draw the same view again.
        let flags: Vec<String> = shaders::settings::Settings::to_texts(camera)
            .iter()
            .map(|(spec, text)| format!("{}={text}", spec.flag()))
            .collect();
        tracing::info!("fitted camera: --{}", flags.join(" --"));
    }
    let (reduction, levels, device) = (stats.reduction, stats.level_counts, backend.describe());
    let empty = stats.empty_share * 100.0;
    let limited = if stats.memory_limited {
        format!(
            " (memory-limited: {request_reduction}:1 does not fit the atlas budget)",
            request_reduction = request.reduction
        )
    } else {
        String::new()
    };
    let ms = start.elapsed().as_secs_f64() * 1e3;
    let out = output.write(&encode::png(&frame)?)?;
    say(&format!(
        "wrote {} ({}x{}, {classification}, {}; reduction {reduction:.1}:1{limited} of the \
         shown blocks, {empty:.0} % empty; blocks per level {levels:?}) in {ms:.0} ms on {device}",
        out.display(),
        frame.width,
        frame.height,
        request.shading
    ))
}

/// A file a command writes when its work is done, checked before the work: a
/// folder that does not exist or cannot be written is refused at once. A
/// regular file is written beside its place and renamed into it when complete,
/// so a failure leaves no partial file; anything else that exists (a device,
/// a pipe) is opened at once and written in place.
enum OutputFile {
    Replace {
        path: PathBuf,
        temp: tempfile::NamedTempFile,
    },
    InPlace {
        path: PathBuf,
        file: std::fs::File,
    },
}

impl OutputFile {
    fn prepare(path: PathBuf) -> anyhow::Result<OutputFile> {
        let cannot = || format!("cannot write {}", path.display());
        match std::fs::metadata(&path) {
            Ok(meta) if meta.is_dir() => {
                anyhow::bail!("{}: a folder: expected a file name", cannot())
            }
            Ok(meta) if !meta.is_file() => {
                let file = std::fs::OpenOptions::new()
                    .write(true)
                    .open(&path)
                    .with_context(cannot)?;
                return Ok(OutputFile::InPlace { path, file });
            }
            _ => {}
        }
        let folder = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => std::path::Path::new("."),
        };
        let mut builder = tempfile::Builder::new();
        builder.prefix(".voxserve-").suffix(".partial");
        // A file anyone may read, as the umask allows (not the owner-only
        // mode of temporary files).
        #[cfg(unix)]
        builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
        let temp = builder.tempfile_in(folder).with_context(cannot)?;
        Ok(OutputFile::Replace { path, temp })
    }

    /// Writes `bytes` and returns the path written.
    fn write(self, bytes: &[u8]) -> anyhow::Result<PathBuf> {
        match self {
            OutputFile::Replace { path, mut temp } => {
                let cannot = || format!("cannot write {}", path.display());
                temp.write_all(bytes).with_context(cannot)?;
                temp.persist(&path).with_context(cannot)?;
                Ok(path)
            }
            OutputFile::InPlace { path, mut file } => {
                file.write_all(bytes)
                    .with_context(|| format!("cannot write {}", path.display()))?;
                Ok(path)
            }
        }
    }
}

/// `voxserve info`: what a file or DICOM folder holds, and its value statistics
/// (a full read, slab by slab).
pub fn info(args: &InfoArgs) -> anyhow::Result<()> {
    let leftover = args
        .path
        .file_name()
        .and_then(|n| blocks::store::ingest::leftover_of(&n.to_string_lossy()).map(|_| ()))
        .is_some();
    if blocks::store::is_url(&args.path.to_string_lossy())
        || blocks::store::Store::is_store(&args.path)
        || (leftover && args.path.is_dir())
    {
        return store_info(args);
    }
    let Opened { mut source, series } = open_for_info(args)?;
    let info = source.info().clone();
    let bar = progress_bar(u64::from(info.geometry.dims[2]), "reading slices");
    let stats = ingest::scan(source.as_mut(), |z| bar.set_position(u64::from(z)))?;
    bar.finish_and_clear();
    if args.json {
        let json = info_json(&info, &stats, series.as_deref());
        return say(&serde_json::to_string_pretty(&json)?);
    }
    say(&info_text(&info, &stats, series.as_deref()).join("\n"))
}

/// The volume `info` reads, and the series of its DICOM folder (none for a file).
struct Opened {
    source: Box<dyn VolumeSource>,
    series: Option<Vec<SeriesSummary>>,
}

/// Opens the file, or the series of the DICOM folder that `--series` names.
/// A folder of several series lists them first when none is named and the
/// output is text.
fn open_for_info(args: &InfoArgs) -> anyhow::Result<Opened> {
    let options = args.input.open_options();
    if !args.path.is_dir() {
        return Ok(Opened {
            source: ingest::open(&args.path, &options)?,
            series: None,
        });
    }
    let scan = FolderScan::new(&args.path, options.allow_data_outside)?;
    let summaries = scan.summaries();
    if summaries.len() > 1 && options.series.is_none() && !args.json {
        say(&format!(
            "{}: {} DICOM series",
            args.path.display(),
            summaries.len()
        ))?;
        for s in &summaries {
            say(&format!("  {s}"))?;
        }
    }
    Ok(Opened {
        source: Box::new(scan.open(options.series.as_deref())?),
        series: Some(summaries),
    })
}

/// The physical values of `stats`' stored range, lowest first.
fn physical_range(info: &VolumeInfo, stats: &VolumeStats) -> [f64; 2] {
    let physical = stats.stored_range.map(|v| info.value_map.physical(v));
    [physical[0].min(physical[1]), physical[0].max(physical[1])]
}

/// `info`'s JSON output.
fn info_json(
    info: &VolumeInfo,
    stats: &VolumeStats,
    series: Option<&[SeriesSummary]>,
) -> serde_json::Value {
    serde_json::json!({
        "path": info.path,
        "format": info.format.to_string(),
        "dims": info.geometry.dims,
        "voxel_type": info.voxel_type.name(),
        "spacing": info.geometry.spacing,
        "origin": info.geometry.origin,
        "direction": info.geometry.direction,
        "value_map": { "slope": info.value_map.slope, "intercept": info.value_map.intercept },
        "stored_range": stats.stored_range,
        "value_range": physical_range(info, stats),
        "mean_stored": stats.mean,
        "mean": info.value_map.physical(stats.mean),
        "nan_voxels": stats.nans,
        "unit": info.unit,
        "modality": info.modality,
        "description": info.description,
        "notes": info.notes,
        "series": series.map(|list| list.iter().map(|s| serde_json::json!({
            "id": s.id, "modality": s.modality, "description": s.description,
            "slices": s.slices, "columns": s.size[0], "rows": s.size[1],
        })).collect::<Vec<_>>()),
    })
}

/// `info`'s text output, line by line.
fn info_text(
    info: &VolumeInfo,
    stats: &VolumeStats,
    series: Option<&[SeriesSummary]>,
) -> Vec<String> {
    let [lo, hi] = physical_range(info, stats);
    let unit = info
        .unit
        .as_deref()
        .map(|u| format!(" {u}"))
        .unwrap_or_default();
    let mut lines = vec![
        format!("path:        {}", info.path.display()),
        format!("format:      {}", info.format),
    ];
    lines.extend(geometry_lines(&info.geometry, info.voxel_type.name()));
    lines.extend([
        format!(
            "value map:   physical = stored × {} + {}",
            g(f64::from(info.value_map.slope)),
            g(f64::from(info.value_map.intercept))
        ),
        format!(
            "values:      {} … {}{unit}, mean {}{unit} (stored {} … {}, mean {})",
            g(lo),
            g(hi),
            g(info.value_map.physical(stats.mean)),
            g(stats.stored_range[0]),
            g(stats.stored_range[1]),
            g(stats.mean)
        ),
        format!(
            "modality:    {}",
            info.modality.as_deref().unwrap_or("unknown")
        ),
    ]);
    if stats.nans > 0 {
        lines.push(format!("NaN voxels:  {}", stats.nans));
    }
    if let Some(d) = &info.description {
        lines.push(format!("description: {d}"));
    }
    if let Some(list) = series {
        lines.push(format!("series:      {} in the folder", list.len()));
        lines.extend(list.iter().map(|s| format!("  {s}")));
    }
    lines.extend(info.notes.iter().map(|n| format!("note:        {n}")));
    lines
}

/// `voxserve ingest`: a brick store from a volume file or DICOM folder.
pub fn ingest(args: &IngestArgs) -> anyhow::Result<()> {
    let mut source = ingest::open(&args.input, &args.input_options.open_options())?;
    write_store(source.as_mut(), &args.out, args.force, args.zstd_level)?.say()
}

/// A brick store [`write_store`] wrote.
#[derive(Debug, Clone)]
pub struct Written {
    /// Where: the folder, or the object-store URL.
    pub store: String,
    /// What the ingest wrote.
    pub summary: blocks::store::IngestSummary,
    /// Seconds the upload to object storage took (after the ingest into a
    /// local folder), when the store went there.
    pub upload_seconds: Option<f64>,
}

impl Written {
    /// Says what was written, in one line.
    pub fn say(&self) -> anyhow::Result<()> {
        let summary = &self.summary;
        let [x, y, z] = summary.dims;
        say(&format!(
            "wrote {}: {x} × {y} × {z} {} voxels, {} blocks of 16³ ({} uniform) at 5 levels; \
             {:.1} MB of voxels in {:.1} MB (compression {:.2}:1); {:.1} s, {:.0} MB/s",
            self.store,
            summary.voxel_type.name(),
            summary.blocks,
            summary.uniform_blocks,
            summary.source_bytes as f64 / 1e6,
            summary.store_bytes as f64 / 1e6,
            summary.compression_ratio(),
            summary.seconds,
            summary.mb_per_s(),
        ))
    }
}

/// Writes `source` as a brick store at `out` (a folder, or an object-store
/// URL: written to a local folder, then uploaded) with a progress bar.
pub fn write_store(
    source: &mut dyn VolumeSource,
    out: &std::path::Path,
    force: bool,
    zstd_level: i32,
) -> anyhow::Result<Written> {
    let nz = u64::from(source.info().geometry.dims[2]);
    let options = blocks::store::IngestOptions {
        overwrite: force,
        zstd_level,
        fault: std::env::var("VOXSERVE_FAULT_ABORT")
            .ok()
            .and_then(|v| blocks::store::ingest::FaultPoint::parse(&v)),
    };
    // A store for object storage is written to a local folder first, then
    // uploaded (blocks::store::remote).
    let out_name = out.to_string_lossy().into_owned();
    let remote = if blocks::store::is_url(&out_name) {
        let remote = blocks::store::Remote::parse(&out_name)?;
        let existing = remote.get(
            blocks::store::manifest::MANIFEST_KEY,
            blocks::store::manifest::MAX_MANIFEST_BYTES,
        )?;
        if existing.is_some() && !force {
            anyhow::bail!(
                "--out {out_name}: a store is there already: expected --force to replace it"
            );
        }
        let staging = tempfile::Builder::new()
            .prefix("voxserve-ingest-")
            .tempdir()
            .context("cannot make a folder to write the store in before uploading it")?;
        Some((remote, staging))
    } else {
        None
    };
    let local;
    let out = match &remote {
        Some((remote, staging)) => {
            local = staging.path().join(remote.name());
            local.as_path()
        }
        None => out,
    };
    let bar = progress_bar(nz, "value range");
    let summary = blocks::store::ingest(source, out, &options, &mut |p| match p {
        blocks::store::IngestProgress::Scanning(z, _) => bar.set_position(u64::from(z)),
        blocks::store::IngestProgress::Writing(z, _) => {
            if bar.message() != "writing" {
                bar.set_message("writing");
            }
            bar.set_position(u64::from(z));
        }
    })?;
    bar.finish_and_clear();
    let mut store = out.display().to_string();
    let mut upload_seconds = None;
    if let Some((remote, _)) = &remote {
        let start = Instant::now();
        let (files, bytes) = remote.upload(out)?;
        let seconds = start.elapsed().as_secs_f64();
        tracing::info!(
            "uploaded {files} files, {:.1} MB, to {} in {seconds:.1} s",
            bytes as f64 / 1e6,
            remote.url(),
        );
        store = remote.url().to_owned();
        upload_seconds = Some(seconds);
    }
    Ok(Written {
        store,
        summary,
        upload_seconds,
    })
}

/// `voxserve verify STORE`: every file against the manifest.
pub fn verify(args: &VerifyArgs) -> anyhow::Result<()> {
    let name = args.store.to_string_lossy();
    let report = if blocks::store::is_url(&name) {
        blocks::store::remote::verify(&name)?
    } else {
        blocks::store::verify(&args.store)?
    };
    let problems = report.problems.len();
    if problems > 0 {
        let lines: Vec<String> = report.problems.iter().map(ToString::to_string).collect();
        anyhow::bail!(
            "{}: {problems} of its files do not match the manifest written at ingest; its \
             voxels cannot be trusted (restore the files or ingest again):\n{}",
            args.store.display(),
            lines.join("\n")
        );
    }
    // The metadata and the statistics, read as the server reads them.
    blocks::store::Store::open(&args.store)?;
    say(&format!(
        "{}: intact: {} files, {:.2} MB, sizes and SHA-256 as written at ingest",
        args.store.display(),
        report.files,
        report.bytes as f64 / 1e6
    ))
}

/// `voxserve info STORE`: the store's metadata and block statistics, no voxels read.
fn store_info(args: &InfoArgs) -> anyhow::Result<()> {
    let store = blocks::store::Store::open(&args.path)?;
    let m = store.meta();
    let stats = store.stats();
    let uniform = (0..stats.block_count())
        .filter(|&b| {
            let [lo, hi] = stats.min_max(0, b);
            lo == hi
        })
        .count();
    let usage = match (store.location(), store.manifest()) {
        (blocks::store::StoreLocation::Remote(_), Some(manifest)) => {
            let bytes = manifest.files.values().map(|f| f.bytes).sum();
            blocks::store::ingest::FolderUsage {
                files: manifest.files.len() as u64 + 1,
                bytes,
                allocated: bytes,
            }
        }
        _ => blocks::store::ingest::folder_usage(&args.path),
    };
    let source_bytes = m.geometry.voxel_count() as f64 * store.voxel_type().size() as f64;
    if args.json {
        return say(&serde_json::to_string_pretty(&serde_json::json!({
            "path": args.path,
            "format": "voxserve brick store (OME-Zarr 0.5)",
            "meta": m,
            "uniform_blocks": uniform,
            "store_files": usage.files,
            "store_bytes": usage.bytes,
            "store_allocated_bytes": usage.allocated,
            "value_range": m.value_range(),
        }))?);
    }
    let [lo, hi] = m.value_range();
    let mut lines = vec![
        format!("path:        {}", args.path.display()),
        "format:      voxserve brick store (OME-Zarr 0.5, 16³ blocks, 5 levels)".to_owned(),
        format!("source:      {} ({})", m.source, m.source_format),
    ];
    lines.extend(geometry_lines(&m.geometry, &m.voxel_type));
    lines.extend([
        format!(
            "values:      {} … {}{}",
            g(lo),
            g(hi),
            m.unit
                .as_deref()
                .map(|u| format!(" {u}"))
                .unwrap_or_default()
        ),
        format!(
            "blocks:      {} × {} × {} ({} uniform)",
            m.blocks[0], m.blocks[1], m.blocks[2], uniform
        ),
        format!(
            "size:        {:.2} MB in {} files ({:.2} MB allocated on disk) for {:.2} MB of \
             voxels ({:.2}:1)",
            usage.bytes as f64 / 1e6,
            usage.files,
            usage.allocated as f64 / 1e6,
            source_bytes / 1e6,
            source_bytes / usage.bytes.max(1) as f64
        ),
        format!(
            "modality:    {}",
            m.modality.as_deref().unwrap_or("unknown")
        ),
    ]);
    lines.extend(m.notes.iter().map(|n| format!("note:        {n}")));
    say(&lines.join("\n"))
}

/// The geometry lines of `info`'s text output.
fn geometry_lines(geometry: &Geometry, voxel_type: &str) -> Vec<String> {
    let Geometry {
        dims,
        spacing,
        origin,
        direction,
    } = *geometry;
    let v3 = |v: [f64; 3]| format!("({}, {}, {})", g(v[0]), g(v[1]), g(v[2]));
    vec![
        format!(
            "dims:        {} × {} × {} voxels",
            dims[0], dims[1], dims[2]
        ),
        format!("voxel type:  {voxel_type}"),
        format!(
            "spacing:     {} × {} × {} mm",
            g(spacing[0]),
            g(spacing[1]),
            g(spacing[2])
        ),
        format!("origin:      {} mm (LPS)", v3(origin)),
        format!(
            "direction:   x {}  y {}  z {}",
            v3(direction[0]),
            v3(direction[1]),
            v3(direction[2])
        ),
    ]
}

/// A number in its shortest form with at most 6 significant digits.
fn g(x: f64) -> String {
    let x = if x == 0.0 { 0.0 } else { x }; // no "-0"
    if x == x.trunc() && x.abs() < 1e15 {
        format!("{x:.0}")
    } else {
        let s = format!("{x:.6}");
        s.trim_end_matches('0').trim_end_matches('.').to_owned()
    }
}

/// A progress bar on standard error, hidden when it is not a terminal.
pub fn progress_bar(len: u64, message: &'static str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len).with_message(message);
    if let Ok(style) =
        indicatif::ProgressStyle::with_template("{msg} {bar:40} {pos}/{len} {elapsed}")
    {
        bar.set_style(style);
    }
    bar
}
