// The one way the console talks to the station: JSON over fetch, errors as ApiError with
// the station's own explanation ({"error": "..."}), never an unexplained failure.

/** An API call that failed: `status` 0 means the station could not be reached. */
export class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.status = status;
  }
}

const listeners = new Set();

// The session's CSRF token (from POST /api/auth/login and GET /api/auth/session): every
// change made on the session cookie must echo it in X-CSRF-Token, which a page of another
// site cannot do because it cannot read this one's answers.
let csrfToken = null;

/** Remembers the session's CSRF token (null when logged out or logins are off). */
export function setCsrfToken(token) {
  csrfToken = token || null;
}

/** Calls `fn` whenever the station answers 401 (not logged in, or the session expired). */
export function onUnauthorized(fn) {
  listeners.add(fn);
}

async function explain(res) {
  const text = await res.text();
  try {
    const body = JSON.parse(text);
    if (body && typeof body.error === 'string') return body.error;
  } catch {
    // Not JSON: a proxy or the browser answered; show what it said.
  }
  return text.trim() || res.statusText || `HTTP ${res.status}`;
}

/**
 * Sends a request; returns the parsed JSON body (or text for non-JSON answers, null for 204).
 * `body` is sent as JSON unless `opts.raw` gives the body and content type.
 */
export async function api(method, path, body, opts = {}) {
  const headers = { Accept: opts.accept || 'application/json' };
  if (csrfToken && !['GET', 'HEAD'].includes(method)) headers['X-CSRF-Token'] = csrfToken;
  let payload;
  if (opts.raw !== undefined) {
    payload = opts.raw;
    headers['Content-Type'] = opts.contentType;
  } else if (body !== undefined) {
    payload = JSON.stringify(body);
    headers['Content-Type'] = 'application/json';
  }
  let res;
  try {
    res = await fetch(path, { method, headers, body: payload, credentials: 'same-origin' });
  } catch (e) {
    throw new ApiError(0, `station unreachable (${e.message})`);
  }
  if (!res.ok) {
    const message = await explain(res);
    if (res.status === 401) listeners.forEach((fn) => fn(message));
    throw new ApiError(res.status, message);
  }
  if (res.status === 204) return null;
  const type = res.headers.get('content-type') || '';
  return type.includes('json') ? res.json() : res.text();
}

/** A readable one-line description of any error, for toasts and inline messages. */
export function describe(e) {
  if (e instanceof ApiError) {
    const what = {
      0: 'Connection',
      400: 'Rejected',
      401: 'Not logged in',
      403: 'Not allowed',
      404: 'Not found',
      409: 'Conflict',
      413: 'Too large',
      422: 'Rejected',
      429: 'Too many attempts',
      503: 'Busy',
    }[e.status];
    return `${what || `Error ${e.status}`}: ${e.message}`;
  }
  return String(e && e.message ? e.message : e);
}
