//! Operator logins, roles and API tokens (`[console.auth]`).
//!
//! - Three roles, each including the one below: `viewer` (sees everything), `operator`
//!   (also dispatches and aborts missions and tasks, acknowledges events, subscribes to
//!   environment data), `admin` (also manages rules, vehicles, users and tokens).
//! - People log in with a name and password (`POST /api/auth/login`) and get a session in
//!   an `HttpOnly`, `SameSite=Strict` cookie (`Secure` over TLS) and a CSRF token that
//!   every state-changing request on that session must echo in `X-CSRF-Token`; tools send
//!   `Authorization: Bearer <token>`.
//! - Users and tokens live in a JSON file (`users_path`): passwords as Argon2id PHC
//!   strings, tokens and session ids only as SHA-256 digests. The first start with auth
//!   enabled and no admin creates user `admin` and an admin token; the caller shows them
//!   once on the terminal (never in the log) unless they came from the configuration.
//! - Missing or invalid credentials give 401, the wrong role 403, both as `{"error": ...}`.
//! - Failed logins are limited per client address and per user name ([`LoginThrottle`]),
//!   and Argon2 hashing is bounded by a semaphore, so a login flood neither guesses
//!   passwords quickly nor takes every blocking thread.

use std::collections::{HashMap, VecDeque};
use std::net::IpAddr;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use argon2::Argon2;
use argon2::password_hash::{PasswordHash, PasswordHasher, PasswordVerifier, SaltString};
use axum::http::{HeaderMap, Method, header};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

/// Name of the session cookie.
pub const COOKIE: &str = "shoal_session";

/// The header a state-changing request on a session cookie carries its CSRF token in.
pub const CSRF_HEADER: &str = "x-csrf-token";

/// What a user or token may do; each role includes the ones before it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Reads everything, changes nothing.
    Viewer,
    /// Also plans, starts and aborts missions and tasks, acknowledges events.
    Operator,
    /// Also manages rules, vehicles, users and tokens.
    Admin,
}

impl std::fmt::Display for Role {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Viewer => "viewer",
            Self::Operator => "operator",
            Self::Admin => "admin",
        })
    }
}

/// The `[console.auth]` section of Shoal's configuration.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AuthConfig {
    /// Require a login or token for the API and the live feed. On by default; turning it
    /// off leaves the console open to anyone who can reach `console.listen`.
    pub enabled: bool,
    /// Users and API tokens (hashes only), managed through `/api/auth/users` and
    /// `/api/auth/tokens`; created on the first start with `enabled = true`.
    pub users_path: PathBuf,
    /// How long a login lasts, seconds.
    pub session_ttl_s: u64,
    /// The first admin's password on the first start (at least 10 characters), instead of
    /// a random one printed on the terminal; empty: random. For test harnesses and
    /// provisioning (`SHOAL_CONSOLE__AUTH__INITIAL_ADMIN_PASSWORD`); unused once an admin
    /// exists. Shown as `<redacted>` by `shoal config`.
    #[serde(serialize_with = "redacted")]
    pub initial_admin_password: String,
    /// The first admin API token on the first start (at least 32 characters), instead of a
    /// random one printed on the terminal; empty: random. Shown as `<redacted>`.
    #[serde(serialize_with = "redacted")]
    pub initial_admin_token: String,
    /// Failed logins allowed per client address and per user name within
    /// `failed_login_window_s`; past that, logins are answered 429 with `Retry-After`.
    pub max_failed_logins: u32,
    /// The window failed logins are counted over, seconds.
    pub failed_login_window_s: u64,
    /// Password hashes (Argon2, tens of ms and 19 MiB each) computed at once at most.
    pub max_concurrent_hashes: usize,
    /// How long a login waits for a hashing turn before 503, ms.
    pub hash_queue_ms: u64,
}

/// A credential as the printed configuration shows it: whether one is set, never what.
fn redacted<S: serde::Serializer>(value: &str, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(if value.is_empty() { "" } else { "<redacted>" })
}

impl Default for AuthConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            users_path: PathBuf::from("shoal-data/console-users.json"),
            session_ttl_s: 12 * 3600,
            initial_admin_password: String::new(),
            initial_admin_token: String::new(),
            max_failed_logins: 5,
            failed_login_window_s: 60,
            max_concurrent_hashes: 2,
            hash_queue_ms: 1000,
        }
    }
}

impl AuthConfig {
    /// Logins off: for tests and tools that start a console of their own.
    pub fn off() -> Self {
        Self {
            enabled: false,
            ..Self::default()
        }
    }
}

/// Why the authentication store cannot be used or changed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AuthError {
    /// The users file cannot be read or written.
    #[error("users file {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What failed.
        source: std::io::Error,
    },
    /// The users file is not valid JSON of the expected shape.
    #[error("users file {path}: {source}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        source: serde_json::Error,
    },
    /// The operating system's random source failed.
    #[error("no randomness for salts and tokens: {0}")]
    Random(String),
    /// Hashing failed (should not happen with valid parameters).
    #[error("password hashing failed: {0}")]
    Hash(String),
    /// A request to change users or tokens is wrong; the text says how.
    #[error("{0}")]
    Invalid(String),
    /// No such user or token.
    #[error("{0}")]
    NotFound(String),
    /// The change would leave the station without an admin.
    #[error("{0} is the last admin: make another admin first")]
    LastAdmin(String),
    /// Authentication is switched off, so there is nothing to manage.
    #[error("authentication is disabled ([console.auth] enabled = false)")]
    Disabled,
    /// The name and password do not match (deliberately not saying which).
    #[error("wrong user name or password")]
    BadCredentials,
}

/// Who made a request.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Identity {
    /// User name, or the token's name.
    pub name: String,
    /// What they may do.
    pub role: Role,
    /// `session`, `token`, or `open` when authentication is disabled.
    pub via: &'static str,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct UserRecord {
    name: String,
    role: Role,
    /// Argon2id PHC string (salt and parameters included).
    password_hash: String,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TokenRecord {
    id: String,
    name: String,
    role: Role,
    /// Hex SHA-256 of the token: tokens are long random strings, so a fast hash suffices.
    sha256: String,
    created_ms: i64,
}

#[derive(Debug, Default, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct UsersFile {
    users: Vec<UserRecord>,
    tokens: Vec<TokenRecord>,
}

/// A user as the API lists it (no hash).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct UserInfo {
    /// Login name.
    pub name: String,
    /// Role.
    pub role: Role,
}

/// A token as the API lists it (never the token itself).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct TokenInfo {
    /// Identifier, for deleting it.
    pub id: String,
    /// The tool it is for.
    pub name: String,
    /// Role.
    pub role: Role,
    /// When it was made, ms since the Unix epoch.
    pub created_ms: i64,
}

/// Credentials made on the first start, shown once on the terminal.
#[derive(Debug, Clone)]
pub struct Bootstrap {
    /// The admin's login name.
    pub user: String,
    /// The admin's password.
    pub password: String,
    /// An admin API token.
    pub token: String,
    /// The password came from `initial_admin_password`: whoever set it knows it.
    pub password_configured: bool,
    /// The token came from `initial_admin_token`.
    pub token_configured: bool,
}

impl Bootstrap {
    /// What to print on the terminal once: the credentials nobody knows yet.
    pub fn notice(&self, users_file: &Path) -> String {
        let mut text = format!(
            "\n=== Shoal console: first start, user \"{}\" (admin) created in {} ===\n",
            self.user,
            users_file.display()
        );
        if self.password_configured {
            text.push_str("  password:  the one set in [console.auth] initial_admin_password\n");
        } else {
            text.push_str(&format!("  password:  {}\n", self.password));
        }
        if self.token_configured {
            text.push_str("  API token: the one set in [console.auth] initial_admin_token\n");
        } else {
            text.push_str(&format!("  API token: {}\n", self.token));
        }
        text.push_str(
            "  Shown only now and never logged; only their hashes are stored. Change the password\n  \
             with POST /api/auth/users (see docs/console.md, \"Authentication\").\n\n",
        );
        text
    }
}

#[derive(Debug)]
struct Session {
    identity: Identity,
    expires_ms: i64,
}

#[derive(Debug, Default)]
struct Inner {
    file: UsersFile,
    /// SHA-256 of the session id -> session; sessions end with the process.
    sessions: HashMap<String, Session>,
}

/// The authentication store: users, tokens and live sessions.
#[derive(Debug)]
pub struct Auth {
    enabled: bool,
    path: PathBuf,
    ttl_ms: i64,
    inner: Mutex<Inner>,
    /// A real Argon2 hash checked when the user does not exist, so an unknown user and a
    /// wrong password take equally long (no user enumeration by timing).
    decoy_hash: String,
}

fn now_ms() -> i64 {
    shoal_model::now_ms()
}

fn random_hex(bytes: usize) -> Result<String, AuthError> {
    let mut buf = vec![0u8; bytes];
    getrandom::fill(&mut buf).map_err(|e| AuthError::Random(e.to_string()))?;
    Ok(hex::encode(buf))
}

fn sha256_hex(secret: &str) -> String {
    hex::encode(Sha256::digest(secret.as_bytes()))
}

/// An Argon2id PHC string for `password` with a fresh random salt.
pub fn hash_password(password: &str) -> Result<String, AuthError> {
    let mut salt = [0u8; 16];
    getrandom::fill(&mut salt).map_err(|e| AuthError::Random(e.to_string()))?;
    let salt = SaltString::encode_b64(&salt).map_err(|e| AuthError::Hash(e.to_string()))?;
    Argon2::default()
        .hash_password(password.as_bytes(), &salt)
        .map(|h| h.to_string())
        .map_err(|e| AuthError::Hash(e.to_string()))
}

fn verify_password(password: &str, phc: &str) -> bool {
    PasswordHash::new(phc).is_ok_and(|h| {
        Argon2::default()
            .verify_password(password.as_bytes(), &h)
            .is_ok()
    })
}

fn check_name(what: &str, name: &str) -> Result<(), AuthError> {
    let ok = (1..=32).contains(&name.len())
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'.' | b'-'));
    if ok {
        Ok(())
    } else {
        Err(AuthError::Invalid(format!(
            "{what}: 1 to 32 letters, digits, '_', '.' or '-'"
        )))
    }
}

/// Least password length for users made through the API.
pub const MIN_PASSWORD_LEN: usize = 10;

/// Least length of a token given in the configuration (generated ones have 70).
pub const MIN_TOKEN_LEN: usize = 32;

impl Auth {
    /// No authentication: every request is allowed, as an `open` admin.
    pub fn disabled() -> Self {
        Self {
            enabled: false,
            path: PathBuf::new(),
            ttl_ms: 0,
            inner: Mutex::new(Inner::default()),
            decoy_hash: String::new(),
        }
    }

    /// Opens the store for `config`; with auth enabled and no admin yet, creates one and
    /// returns its credentials (to be shown once).
    pub fn load(config: &AuthConfig) -> Result<(Self, Option<Bootstrap>), AuthError> {
        if !config.enabled {
            return Ok((Self::disabled(), None));
        }
        let path = config.users_path.clone();
        let file = match std::fs::read(&path) {
            Ok(bytes) => serde_json::from_slice(&bytes).map_err(|source| AuthError::Parse {
                path: path.clone(),
                source,
            })?,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => UsersFile::default(),
            Err(source) => return Err(AuthError::Io { path, source }),
        };
        let ttl_ms = i64::try_from(config.session_ttl_s.saturating_mul(1000)).unwrap_or(i64::MAX);
        let auth = Self {
            enabled: true,
            path,
            ttl_ms,
            inner: Mutex::new(Inner {
                file,
                sessions: HashMap::new(),
            }),
            decoy_hash: hash_password("not a password anyone has")?,
        };
        let has_admin = auth.lock().file.users.iter().any(|u| u.role == Role::Admin);
        if has_admin {
            return Ok((auth, None));
        }
        let password_configured = !config.initial_admin_password.is_empty();
        let password = if password_configured {
            config.initial_admin_password.clone()
        } else {
            random_hex(12)?
        };
        let token_configured = !config.initial_admin_token.is_empty();
        if token_configured && config.initial_admin_token.chars().count() < MIN_TOKEN_LEN {
            return Err(AuthError::Invalid(format!(
                "[console.auth] initial_admin_token: at least {MIN_TOKEN_LEN} characters"
            )));
        }
        auth.set_user("admin", &password, Role::Admin)
            .map_err(|e| match e {
                AuthError::Invalid(why) => {
                    AuthError::Invalid(format!("[console.auth] initial_admin_password: {why}"))
                }
                e => e,
            })?;
        let token = if token_configured {
            auth.add_token("bootstrap", Role::Admin, &config.initial_admin_token)?;
            config.initial_admin_token.clone()
        } else {
            auth.create_token("bootstrap", Role::Admin)?.1
        };
        let boot = Bootstrap {
            user: "admin".into(),
            password,
            token,
            password_configured,
            token_configured,
        };
        Ok((auth, Some(boot)))
    }

    /// True when requests must carry credentials.
    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// Where users and tokens are kept.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Session lifetime, seconds (for the cookie's Max-Age).
    pub fn ttl_s(&self) -> i64 {
        self.ttl_ms / 1000
    }

    fn lock(&self) -> MutexGuard<'_, Inner> {
        self.inner
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    fn save(&self, file: &UsersFile) -> Result<(), AuthError> {
        let io = |source| AuthError::Io {
            path: self.path.clone(),
            source,
        };
        if let Some(dir) = self.path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(io)?;
        }
        let json = serde_json::to_vec_pretty(file).map_err(|source| AuthError::Parse {
            path: self.path.clone(),
            source,
        })?;
        // Written aside and renamed, so a crash leaves the old file or the new one.
        let tmp = self.path.with_extension("json.tmp");
        std::fs::write(&tmp, json).map_err(io)?;
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&tmp, std::fs::Permissions::from_mode(0o600)).map_err(io)?;
        }
        std::fs::rename(&tmp, &self.path).map_err(io)
    }

    /// Who sent these headers: a bearer token, else the session cookie.
    /// The error is the reason to give with 401.
    pub fn authenticate(&self, headers: &HeaderMap) -> Result<Identity, &'static str> {
        if !self.enabled {
            return Ok(Identity {
                name: "operator".into(),
                role: Role::Admin,
                via: "open",
            });
        }
        if let Some(value) = headers.get(header::AUTHORIZATION) {
            let token = value
                .to_str()
                .ok()
                .and_then(|v| v.strip_prefix("Bearer "))
                .map(str::trim)
                .ok_or("the Authorization header must be `Bearer <token>`")?;
            let digest = sha256_hex(token);
            let inner = self.lock();
            return inner
                .file
                .tokens
                .iter()
                .find(|t| t.sha256 == digest)
                .map(|t| Identity {
                    name: t.name.clone(),
                    role: t.role,
                    via: "token",
                })
                .ok_or("unknown or revoked API token");
        }
        let session = session_cookie(headers).ok_or("log in first (no session cookie or token)")?;
        let digest = sha256_hex(session);
        let mut inner = self.lock();
        let now = now_ms();
        match inner.sessions.get(&digest) {
            Some(s) if s.expires_ms > now => Ok(s.identity.clone()),
            Some(_) => {
                inner.sessions.remove(&digest);
                Err("the session expired: log in again")
            }
            None => Err("the session ended (logged out or the station restarted): log in again"),
        }
    }

    /// Checks a password and opens a session; returns the session id for the cookie.
    /// Slow on purpose (Argon2): call it off the async threads.
    pub fn login(&self, user: &str, password: &str) -> Result<(String, Identity), AuthError> {
        if !self.enabled {
            return Err(AuthError::Disabled);
        }
        let found = self
            .lock()
            .file
            .users
            .iter()
            .find(|u| u.name == user)
            .cloned();
        let Some(found) = found else {
            verify_password(password, &self.decoy_hash);
            return Err(AuthError::BadCredentials);
        };
        if !verify_password(password, &found.password_hash) {
            return Err(AuthError::BadCredentials);
        }
        let id = random_hex(32)?;
        let identity = Identity {
            name: found.name,
            role: found.role,
            via: "session",
        };
        let now = now_ms();
        let mut inner = self.lock();
        inner.sessions.retain(|_, s| s.expires_ms > now);
        inner.sessions.insert(
            sha256_hex(&id),
            Session {
                identity: identity.clone(),
                expires_ms: now.saturating_add(self.ttl_ms),
            },
        );
        Ok((id, identity))
    }

    /// The CSRF token of the session these headers carry (logged in or not): a digest of
    /// the session id under its own label, so only someone holding the cookie's value,
    /// which scripts cannot read (`HttpOnly`), can produce it, and nothing more is stored.
    pub fn csrf_token(&self, headers: &HeaderMap) -> Option<String> {
        session_cookie(headers).map(csrf_of)
    }

    /// True when the request echoes its session's CSRF token in `X-CSRF-Token`.
    pub fn csrf_ok(&self, headers: &HeaderMap) -> bool {
        let Some(expected) = self.csrf_token(headers) else {
            return false;
        };
        headers
            .get(CSRF_HEADER)
            .and_then(|v| v.to_str().ok())
            .is_some_and(|sent| constant_time_eq(sent.trim().as_bytes(), expected.as_bytes()))
    }

    /// Ends the session these headers carry, if any.
    pub fn logout(&self, headers: &HeaderMap) {
        if let Some(s) = session_cookie(headers) {
            self.lock().sessions.remove(&sha256_hex(s));
        }
    }

    /// Every user, without hashes.
    pub fn users(&self) -> Vec<UserInfo> {
        self.lock()
            .file
            .users
            .iter()
            .map(|u| UserInfo {
                name: u.name.clone(),
                role: u.role,
            })
            .collect()
    }

    /// Creates a user or replaces its password and role; its sessions end.
    pub fn set_user(&self, name: &str, password: &str, role: Role) -> Result<(), AuthError> {
        if !self.enabled {
            return Err(AuthError::Disabled);
        }
        check_name("name", name)?;
        if password.chars().count() < MIN_PASSWORD_LEN {
            return Err(AuthError::Invalid(format!(
                "password: at least {MIN_PASSWORD_LEN} characters"
            )));
        }
        let hash = hash_password(password)?;
        let mut inner = self.lock();
        let mut file = inner.file.clone();
        if role != Role::Admin && would_lose_last_admin(&file, name) {
            return Err(AuthError::LastAdmin(name.to_owned()));
        }
        file.users.retain(|u| u.name != name);
        file.users.push(UserRecord {
            name: name.to_owned(),
            role,
            password_hash: hash,
        });
        file.users.sort_by(|a, b| a.name.cmp(&b.name));
        self.save(&file)?;
        inner.file = file;
        inner
            .sessions
            .retain(|_, s| !(s.identity.via == "session" && s.identity.name == name));
        Ok(())
    }

    /// Deletes a user and ends its sessions; the last admin cannot go.
    pub fn delete_user(&self, name: &str) -> Result<(), AuthError> {
        if !self.enabled {
            return Err(AuthError::Disabled);
        }
        let mut inner = self.lock();
        if !inner.file.users.iter().any(|u| u.name == name) {
            return Err(AuthError::NotFound(format!("no user {name:?}")));
        }
        if would_lose_last_admin(&inner.file, name) {
            return Err(AuthError::LastAdmin(name.to_owned()));
        }
        let mut file = inner.file.clone();
        file.users.retain(|u| u.name != name);
        self.save(&file)?;
        inner.file = file;
        inner
            .sessions
            .retain(|_, s| !(s.identity.via == "session" && s.identity.name == name));
        Ok(())
    }

    /// Every API token, without the secret.
    pub fn tokens(&self) -> Vec<TokenInfo> {
        self.lock()
            .file
            .tokens
            .iter()
            .map(|t| TokenInfo {
                id: t.id.clone(),
                name: t.name.clone(),
                role: t.role,
                created_ms: t.created_ms,
            })
            .collect()
    }

    /// Makes an API token for a tool; the token itself is returned only here.
    pub fn create_token(&self, name: &str, role: Role) -> Result<(TokenInfo, String), AuthError> {
        let token = format!("shoal_{}", random_hex(32)?);
        let info = self.add_token(name, role, &token)?;
        Ok((info, token))
    }

    /// Stores `token` (its digest) for a tool.
    fn add_token(&self, name: &str, role: Role, token: &str) -> Result<TokenInfo, AuthError> {
        if !self.enabled {
            return Err(AuthError::Disabled);
        }
        check_name("name", name)?;
        let record = TokenRecord {
            id: format!("tok-{}", random_hex(6)?),
            name: name.to_owned(),
            role,
            sha256: sha256_hex(token),
            created_ms: now_ms(),
        };
        let info = TokenInfo {
            id: record.id.clone(),
            name: record.name.clone(),
            role,
            created_ms: record.created_ms,
        };
        let mut inner = self.lock();
        let mut file = inner.file.clone();
        file.tokens.push(record);
        self.save(&file)?;
        inner.file = file;
        Ok(info)
    }

    /// Revokes a token.
    pub fn delete_token(&self, id: &str) -> Result<(), AuthError> {
        if !self.enabled {
            return Err(AuthError::Disabled);
        }
        let mut inner = self.lock();
        let mut file = inner.file.clone();
        let before = file.tokens.len();
        file.tokens.retain(|t| t.id != id);
        if file.tokens.len() == before {
            return Err(AuthError::NotFound(format!("no token {id:?}")));
        }
        self.save(&file)?;
        inner.file = file;
        Ok(())
    }
}

fn would_lose_last_admin(file: &UsersFile, name: &str) -> bool {
    let admins: Vec<&str> = file
        .users
        .iter()
        .filter(|u| u.role == Role::Admin)
        .map(|u| u.name.as_str())
        .collect();
    admins == [name]
}

/// The CSRF token belonging to session id `session`.
pub fn csrf_of(session: &str) -> String {
    sha256_hex(&format!("shoal-csrf:{session}"))
}

/// Compares without stopping at the first difference, so timing says nothing about how
/// much of a guess was right.
fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// The session id in the request's cookies.
fn session_cookie(headers: &HeaderMap) -> Option<&str> {
    headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|kv| kv.trim().split_once('='))
        .find(|(k, _)| *k == COOKIE)
        .map(|(_, v)| v)
        .filter(|v| !v.is_empty())
}

/// The `Set-Cookie` value that opens (`Some(id)`) or ends (`None`) a session; `secure`
/// (the console is served over TLS) keeps the browser from ever sending it in clear.
pub fn session_set_cookie(id: Option<&str>, max_age_s: i64, secure: bool) -> String {
    let secure = if secure { "; Secure" } else { "" };
    match id {
        Some(id) => {
            format!("{COOKIE}={id}; HttpOnly; SameSite=Strict; Path=/; Max-Age={max_age_s}{secure}")
        }
        None => format!("{COOKIE}=; HttpOnly; SameSite=Strict; Path=/; Max-Age=0{secure}"),
    }
}

/// Most client addresses and user names whose failures are remembered; past that, the
/// one whose last failure is oldest is forgotten first.
const MAX_TRACKED: usize = 10_000;

/// Failed logins per client address and per user name over a sliding window.
#[derive(Debug)]
pub struct LoginThrottle {
    max: usize,
    window: Duration,
    inner: Mutex<Failures>,
}

#[derive(Debug, Default)]
struct Failures {
    by_addr: HashMap<IpAddr, VecDeque<Instant>>,
    by_user: HashMap<String, VecDeque<Instant>>,
}

/// Drops failures older than the window; true when none are left.
fn expire(times: &mut VecDeque<Instant>, now: Instant, window: Duration) -> bool {
    while times
        .front()
        .is_some_and(|t| now.saturating_duration_since(*t) >= window)
    {
        times.pop_front();
    }
    times.is_empty()
}

fn record<K: std::hash::Hash + Eq + Clone>(
    map: &mut HashMap<K, VecDeque<Instant>>,
    key: &K,
    now: Instant,
    window: Duration,
    max: usize,
) {
    if !map.contains_key(key) && map.len() >= MAX_TRACKED {
        map.retain(|_, t| !expire(t, now, window));
        if map.len() >= MAX_TRACKED
            && let Some(stalest) = map
                .iter()
                .min_by_key(|(_, t)| t.back().copied())
                .map(|(k, _)| k.clone())
        {
            map.remove(&stalest);
        }
    }
    let times = map.entry(key.clone()).or_default();
    times.push_back(now);
    // Only the last `max` matter for the decision.
    while times.len() > max.max(1) {
        times.pop_front();
    }
}

/// The name failures are counted under: no user name is longer than 32 bytes, so every
/// longer one shares one entry (a megabyte-long name must not be kept ten thousand times).
fn user_key(user: &str) -> &str {
    if user.len() <= 32 {
        user
    } else {
        "(name too long)"
    }
}

impl LoginThrottle {
    /// `max` failures per `window` for each address and each user name.
    pub fn new(max: u32, window: Duration) -> Self {
        Self {
            max: usize::try_from(max).unwrap_or(usize::MAX).max(1),
            window,
            inner: Mutex::new(Failures::default()),
        }
    }

    fn lock(&self) -> MutexGuard<'_, Failures> {
        self.inner
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// `Err(wait)` when `addr` or `user` has had its failures within the window: try again
    /// after `wait`.
    pub fn check(&self, addr: Option<IpAddr>, user: &str, now: Instant) -> Result<(), Duration> {
        let mut f = self.lock();
        let (max, window) = (self.max, self.window);
        let wait = |times: Option<&mut VecDeque<Instant>>| -> Option<Duration> {
            let times = times?;
            expire(times, now, window);
            (times.len() >= max).then(|| {
                let oldest = times[times.len() - max];
                window.saturating_sub(now.saturating_duration_since(oldest))
            })
        };
        let by_addr = addr.and_then(|a| wait(f.by_addr.get_mut(&a)));
        let by_user = wait(f.by_user.get_mut(user_key(user)));
        match by_addr.into_iter().chain(by_user).max() {
            Some(w) => Err(w.max(Duration::from_secs(1))),
            None => Ok(()),
        }
    }

    /// Counts a failed login.
    pub fn failed(&self, addr: Option<IpAddr>, user: &str, now: Instant) {
        let mut f = self.lock();
        let (max, window) = (self.max, self.window);
        if let Some(a) = addr {
            record(&mut f.by_addr, &a, now, window, max);
        }
        record(&mut f.by_user, &user_key(user).to_owned(), now, window, max);
    }

    /// A successful login clears its user's failures (not its address's: one known
    /// account must not reset the count for guessing others).
    pub fn succeeded(&self, user: &str) {
        self.lock().by_user.remove(user_key(user));
    }
}

/// `POST` of an MCAP recording whose tracks the replay shows: a read.
const RECORDING_TRACKS: &str = "/api/recordings/tracks";

/// The least role a request needs, or `None` for what anyone may fetch (the console's
/// files, health, the API description, logging in and out, who am I). `/metrics` is a
/// read like any other: a scraper sends a viewer token.
pub fn required_role(method: &Method, path: &str) -> Option<Role> {
    if path == "/metrics" {
        return Some(Role::Viewer);
    }
    if !path.starts_with("/api/") {
        return None;
    }
    if matches!(
        path,
        "/api/health"
            | "/api/openapi.json"
            | "/api/auth/login"
            | "/api/auth/logout"
            | "/api/auth/session"
    ) {
        return None;
    }
    if path.starts_with("/api/auth/") {
        return Some(Role::Admin);
    }
    let reads = matches!(*method, Method::GET | Method::HEAD | Method::OPTIONS);
    // SPARQL over POST is still a read-only query, and reading the tracks of a recording
    // the client sends, or previewing a mission, changes nothing either.
    if reads || matches!(path, "/api/sparql" | "/api/mission-preview") || path == RECORDING_TRACKS {
        return Some(Role::Viewer);
    }
    if path == "/api/rules" || path.starts_with("/api/rules/") || path == "/api/vehicles" {
        return Some(Role::Admin);
    }
    Some(Role::Operator)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use axum::http::HeaderValue;

    fn store() -> (tempfile::TempDir, Auth, Bootstrap) {
        let dir = tempfile::tempdir().unwrap();
        let config = AuthConfig {
            users_path: dir.path().join("users.json"),
            session_ttl_s: 60,
            ..AuthConfig::default()
        };
        let (auth, boot) = Auth::load(&config).unwrap();
        (dir, auth, boot.expect("first start makes an admin"))
    }

    fn with(name: header::HeaderName, value: &str) -> HeaderMap {
        let mut h = HeaderMap::new();
        h.insert(name, HeaderValue::from_str(value).unwrap());
        h
    }

    #[test]
    fn roles_follow_the_method_and_path() {
        use Method as M;
        assert_eq!(required_role(&M::GET, "/"), None);
        assert_eq!(required_role(&M::GET, "/assets/index-1.js"), None);
        assert_eq!(required_role(&M::POST, "/api/auth/login"), None);
        assert_eq!(required_role(&M::GET, "/api/fleet"), Some(Role::Viewer));
        assert_eq!(required_role(&M::GET, "/api/ws"), Some(Role::Viewer));
        assert_eq!(required_role(&M::GET, "/metrics"), Some(Role::Viewer));
        assert_eq!(required_role(&M::GET, "/api/health"), None);
        assert_eq!(required_role(&M::POST, "/api/sparql"), Some(Role::Viewer));
        assert_eq!(
            required_role(&M::POST, "/api/mission-preview"),
            Some(Role::Viewer)
        );
        assert_eq!(
            required_role(&M::POST, "/api/recordings/tracks"),
            Some(Role::Viewer)
        );
        assert_eq!(
            required_role(&M::POST, "/api/missions"),
            Some(Role::Operator)
        );
        assert_eq!(
            required_role(&M::POST, "/api/missions/m1/abort"),
            Some(Role::Operator)
        );
        assert_eq!(required_role(&M::POST, "/api/tasks"), Some(Role::Operator));
        assert_eq!(
            required_role(&M::POST, "/api/abort-all"),
            Some(Role::Operator)
        );
        assert_eq!(required_role(&M::POST, "/api/rules"), Some(Role::Admin));
        assert_eq!(required_role(&M::PATCH, "/api/rules/r1"), Some(Role::Admin));
        assert_eq!(
            required_role(&M::DELETE, "/api/rules/r1"),
            Some(Role::Admin)
        );
        assert_eq!(required_role(&M::POST, "/api/vehicles"), Some(Role::Admin));
        assert_eq!(required_role(&M::GET, "/api/auth/users"), Some(Role::Admin));
        assert!(Role::Viewer < Role::Operator && Role::Operator < Role::Admin);
    }

    #[test]
    fn the_first_start_makes_an_admin_whose_password_and_token_work() {
        let (dir, auth, boot) = store();
        let (session, who) = auth.login(&boot.user, &boot.password).unwrap();
        assert_eq!(who.role, Role::Admin);
        let cookie = with(header::COOKIE, &format!("theme=dark; {COOKIE}={session}"));
        assert_eq!(auth.authenticate(&cookie).unwrap().name, "admin");
        let bearer = with(header::AUTHORIZATION, &format!("Bearer {}", boot.token));
        assert_eq!(auth.authenticate(&bearer).unwrap().via, "token");
        // Only hashes are stored.
        let text = std::fs::read_to_string(dir.path().join("users.json")).unwrap();
        assert!(!text.contains(&boot.password) && !text.contains(&boot.token));
        assert!(text.contains("$argon2id$"));
        // A second start finds the admin and makes nothing.
        let again = Auth::load(&AuthConfig {
            users_path: dir.path().join("users.json"),
            session_ttl_s: 60,
            ..AuthConfig::default()
        })
        .unwrap();
        assert!(again.1.is_none());
        assert!(again.0.login("admin", &boot.password).is_ok());
    }

    #[test]
    fn wrong_credentials_and_ended_sessions_are_refused() {
        let (_dir, auth, boot) = store();
        assert!(matches!(
            auth.login("admin", "wrong password"),
            Err(AuthError::BadCredentials)
        ));
        assert!(matches!(
            auth.login("nobody", &boot.password),
            Err(AuthError::BadCredentials)
        ));
        assert!(auth.authenticate(&HeaderMap::new()).is_err());
        let forged = with(header::COOKIE, &format!("{COOKIE}=0123"));
        assert!(auth.authenticate(&forged).is_err());
        let bad = with(header::AUTHORIZATION, "Bearer shoal_guess");
        assert!(auth.authenticate(&bad).is_err());
        let (session, _) = auth.login("admin", &boot.password).unwrap();
        let cookie = with(header::COOKIE, &format!("{COOKIE}={session}"));
        auth.logout(&cookie);
        assert!(auth.authenticate(&cookie).is_err());
    }

    #[test]
    fn users_and_tokens_are_managed_and_the_last_admin_stays() {
        let (_dir, auth, boot) = store();
        assert!(matches!(
            auth.set_user("vera", "short", Role::Viewer),
            Err(AuthError::Invalid(_))
        ));
        assert!(matches!(
            auth.set_user("bad name", "long enough pw", Role::Viewer),
            Err(AuthError::Invalid(_))
        ));
        auth.set_user("vera", "long enough pw", Role::Viewer)
            .unwrap();
        let (_, who) = auth.login("vera", "long enough pw").unwrap();
        assert_eq!(who.role, Role::Viewer);
        assert!(matches!(
            auth.delete_user("admin"),
            Err(AuthError::LastAdmin(_))
        ));
        assert!(matches!(
            auth.set_user("admin", &boot.password, Role::Operator),
            Err(AuthError::LastAdmin(_))
        ));
        let (info, token) = auth.create_token("ci-tool", Role::Operator).unwrap();
        let bearer = with(header::AUTHORIZATION, &format!("Bearer {token}"));
        assert_eq!(auth.authenticate(&bearer).unwrap().role, Role::Operator);
        auth.delete_token(&info.id).unwrap();
        assert!(auth.authenticate(&bearer).is_err());
        assert!(matches!(
            auth.delete_token(&info.id),
            Err(AuthError::NotFound(_))
        ));
        auth.delete_user("vera").unwrap();
        assert_eq!(auth.users().len(), 1);
    }

    #[test]
    fn disabled_auth_lets_everyone_in_and_manages_nothing() {
        let auth = Auth::disabled();
        assert_eq!(auth.authenticate(&HeaderMap::new()).unwrap().via, "open");
        assert!(matches!(auth.login("a", "b"), Err(AuthError::Disabled)));
        assert!(matches!(
            auth.set_user("a", "long enough pw", Role::Admin),
            Err(AuthError::Disabled)
        ));
    }

    #[test]
    fn the_session_cookie_is_http_only_and_same_site_and_secure_over_tls() {
        let c = session_set_cookie(Some("abc"), 60, false);
        assert!(c.starts_with("shoal_session=abc;"));
        assert!(c.contains("HttpOnly") && c.contains("SameSite=Strict"));
        assert!(!c.contains("Secure"));
        assert!(session_set_cookie(Some("abc"), 60, true).ends_with("; Secure"));
        assert!(session_set_cookie(None, 60, false).contains("Max-Age=0"));
        assert!(session_set_cookie(None, 60, true).contains("Secure"));
    }

    #[test]
    fn logins_are_on_by_default() {
        assert!(AuthConfig::default().enabled);
        assert!(!AuthConfig::off().enabled);
    }

    #[test]
    fn the_first_admin_can_come_from_the_configuration_and_is_then_not_shown() {
        let dir = tempfile::tempdir().unwrap();
        let config = AuthConfig {
            users_path: dir.path().join("users.json"),
            initial_admin_password: "configured password".into(),
            initial_admin_token: "t".repeat(MIN_TOKEN_LEN),
            ..AuthConfig::default()
        };
        let (auth, boot) = Auth::load(&config).unwrap();
        let boot = boot.unwrap();
        assert!(boot.password_configured && boot.token_configured);
        assert!(auth.login("admin", "configured password").is_ok());
        let bearer = with(header::AUTHORIZATION, &format!("Bearer {}", "t".repeat(32)));
        assert_eq!(auth.authenticate(&bearer).unwrap().role, Role::Admin);
        let notice = boot.notice(auth.path());
        assert!(!notice.contains("configured password") && !notice.contains(&"t".repeat(32)));
        // A random one is shown, once.
        let (_d, auth, boot) = store();
        let notice = boot.notice(auth.path());
        assert!(notice.contains(&boot.password) && notice.contains(&boot.token));
        // Weak configured credentials are refused, naming the key.
        for (password, token) in [("short", ""), ("long enough pw", "short token")] {
            let dir = tempfile::tempdir().unwrap();
            let err = Auth::load(&AuthConfig {
                users_path: dir.path().join("users.json"),
                initial_admin_password: password.into(),
                initial_admin_token: token.into(),
                ..AuthConfig::default()
            })
            .unwrap_err();
            assert!(err.to_string().contains("initial_admin"), "{err}");
        }
    }

    #[test]
    fn the_csrf_token_belongs_to_the_session_cookie() {
        let (_dir, auth, boot) = store();
        let (session, _) = auth.login("admin", &boot.password).unwrap();
        let mut h = with(header::COOKIE, &format!("{COOKIE}={session}"));
        let token = auth.csrf_token(&h).unwrap();
        assert_eq!(token, csrf_of(&session));
        assert_ne!(
            token,
            sha256_hex(&session),
            "the stored digest is not the token"
        );
        assert!(!auth.csrf_ok(&h), "no header");
        h.insert(
            CSRF_HEADER,
            HeaderValue::from_str(&csrf_of("other")).unwrap(),
        );
        assert!(!auth.csrf_ok(&h), "another session's token");
        h.insert(CSRF_HEADER, HeaderValue::from_str(&token).unwrap());
        assert!(auth.csrf_ok(&h));
        assert!(!auth.csrf_ok(&with(header::HeaderName::from_static(CSRF_HEADER), &token)));
    }

    #[test]
    fn failed_logins_are_limited_per_address_and_per_user_over_a_window() {
        let t = LoginThrottle::new(5, Duration::from_secs(60));
        let t0 = Instant::now();
        let a: IpAddr = "127.0.0.7".parse().unwrap();
        let b: IpAddr = "127.0.0.8".parse().unwrap();
        for i in 0..5 {
            assert!(t.check(Some(a), "admin", t0).is_ok(), "attempt {i}");
            t.failed(Some(a), "admin", t0 + Duration::from_secs(i));
        }
        let now = t0 + Duration::from_secs(10);
        // The address is blocked, whatever the name; the oldest failure leaves in 50 s.
        assert_eq!(t.check(Some(a), "vera", now), Err(Duration::from_secs(50)));
        // The name is blocked from another address too.
        assert!(t.check(Some(b), "admin", now).is_err());
        assert!(t.check(Some(b), "vera", now).is_ok());
        // Success clears the name but not the address.
        t.succeeded("admin");
        assert!(t.check(Some(b), "admin", now).is_ok());
        assert!(t.check(Some(a), "vera", now).is_err());
        // A minute after the first failure, one more attempt is allowed.
        assert!(
            t.check(Some(a), "vera", t0 + Duration::from_secs(60))
                .is_ok()
        );
        // Without a known address, the name alone counts.
        for _ in 0..5 {
            t.failed(None, "otto", now);
        }
        assert!(t.check(None, "otto", now).is_err());
        // Names no user can have share one entry, however many and long.
        for i in 0..5 {
            t.failed(None, &format!("{i}{}", "x".repeat(1 << 16)), now);
        }
        assert!(t.check(None, &"y".repeat(100), now).is_err());
        assert!(t.lock().by_user.keys().all(|k| k.len() <= 32));
    }

    #[test]
    fn the_throttle_forgets_the_stalest_entries_past_its_bound() {
        let t = LoginThrottle::new(1, Duration::from_secs(60));
        let t0 = Instant::now();
        for i in 0..(MAX_TRACKED + 10) {
            t.failed(None, &format!("u{i}"), t0 + Duration::from_millis(i as u64));
        }
        let f = t.lock();
        assert_eq!(f.by_user.len(), MAX_TRACKED);
        assert!(!f.by_user.contains_key("u0") && f.by_user.contains_key("u10009"));
    }
}
