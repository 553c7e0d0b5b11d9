// Logging in, when the server asks for tokens (GET /api/auth says whether).
//
// A token comes, in this order, from
// 1. a launch URL (`?access_token=…` or `#access_token=…`, as PACS launch
//    integrations send it): taken, and removed from the address bar at once;
// 2. the return from the issuer's login page (`?code=…&state=…`): the code
//    is exchanged at the issuer's token endpoint with the PKCE verifier this
//    page made before it left (authorization-code flow with PKCE, S256);
// 3. this tab's session storage, while the token has not expired;
// 4. else the page goes to the issuer's login page.
// The token rides on every API request (Authorization: Bearer) and on the
// WebSocket as the subprotocol `bearer.TOKEN` beside `voxserve`.

const TOKEN_KEY = 'voxserve.token';
const PKCE_KEY = 'voxserve.pkce';
// A token this close to its expiry is not used: the next login gets another.
const EXPIRY_MARGIN_S = 30;

let token = null;

function base64url(bytes) {
  let text = '';
  for (const b of bytes) text += String.fromCharCode(b);
  return btoa(text).replace(/\+/g, '-').replace(/\//g, '_').replace(/=+$/, '');
}

function randomText(bytes) {
  return base64url(crypto.getRandomValues(new Uint8Array(bytes)));
}

// Seconds until a JWT expires (Infinity for tokens that are not JWTs, such
// as API tokens, which do not expire).
function secondsLeft(jwt) {
  const parts = jwt.split('.');
  if (parts.length !== 3) return Infinity;
  try {
    const claims = JSON.parse(atob(parts[1].replace(/-/g, '+').replace(/_/g, '/')));
    return typeof claims.exp === 'number' ? claims.exp - Date.now() / 1000 : Infinity;
  } catch {
    return Infinity;
  }
}

// This page's address without the login's query parameters: the redirect
// URI, and what the address bar shows once logged in.
function cleanUrl() {
  const url = new URL(location.href);
  for (const name of ['access_token', 'code', 'state', 'session_state', 'iss', 'token_type', 'expires_in']) {
    url.searchParams.delete(name);
  }
  if (new URLSearchParams(url.hash.slice(1)).has('access_token')) url.hash = '';
  return url;
}

// Exchanges the login's code for a token; puts back the view the address
// held before the login (its hash: a redirect URI carries none).
async function exchange(oidc, code, state) {
  const saved = JSON.parse(sessionStorage.getItem(PKCE_KEY) || 'null');
  sessionStorage.removeItem(PKCE_KEY);
  if (!saved || saved.state !== state) {
    throw new Error('the login came back with a state this page did not send: log in again');
  }
  if (saved.view) history.replaceState(null, '', `${cleanUrl().toString()}${saved.view}`);
  const body = new URLSearchParams({
    grant_type: 'authorization_code',
    code,
    redirect_uri: saved.redirect_uri,
    client_id: oidc.client_id,
    code_verifier: saved.verifier,
  });
  const response = await fetch(oidc.token_endpoint, { method: 'POST', body });
  const answer = await response.json().catch(() => ({}));
  if (!response.ok || typeof answer.access_token !== 'string') {
    throw new Error(`the issuer did not give a token (HTTP ${response.status}${answer.error ? `: ${answer.error}` : ''})`);
  }
  return answer.access_token;
}

async function redirectToLogin(oidc) {
  const verifier = randomText(32);
  const digest = await crypto.subtle.digest('SHA-256', new TextEncoder().encode(verifier));
  const state = randomText(16);
  const back = cleanUrl();
  const view = back.hash;
  back.hash = '';
  const redirectUri = back.toString();
  sessionStorage.setItem(PKCE_KEY, JSON.stringify({ verifier, state, redirect_uri: redirectUri, view }));
  const url = new URL(oidc.authorization_endpoint);
  url.search = new URLSearchParams({
    response_type: 'code',
    client_id: oidc.client_id,
    redirect_uri: redirectUri,
    scope: oidc.scopes,
    state,
    code_challenge: base64url(new Uint8Array(digest)),
    code_challenge_method: 'S256',
  }).toString();
  location.assign(url.toString());
  // The page is leaving.
  return new Promise(() => {});
}

// Gets a token if the server needs one; resolves when requests can be made.
export async function logIn() {
  const response = await fetch('/api/auth');
  if (!response.ok) throw new Error(`GET /api/auth answered ${response.status}`);
  const config = await response.json();
  if (!config.required) return;
  const url = new URL(location.href);
  const launched = url.searchParams.get('access_token') ||
    new URLSearchParams(url.hash.slice(1)).get('access_token');
  const code = url.searchParams.get('code');
  const state = url.searchParams.get('state');
  if (launched || (code && state)) history.replaceState(null, '', cleanUrl().toString());
  if (launched) {
    token = launched;
  } else if (code && state && config.oidc) {
    token = await exchange(config.oidc, code, state);
  } else {
    const stored = sessionStorage.getItem(TOKEN_KEY);
    if (stored && secondsLeft(stored) > EXPIRY_MARGIN_S) token = stored;
  }
  if (token) {
    sessionStorage.setItem(TOKEN_KEY, token);
    return;
  }
  if (config.oidc && config.oidc.client_id && config.oidc.authorization_endpoint) {
    await redirectToLogin(config.oidc);
  }
  throw new Error('this server needs an access token: open it from your launch link, or ask for an API token');
}

// Forgets the token (refused or expired) and logs in again.
export function logInAgain() {
  sessionStorage.removeItem(TOKEN_KEY);
  token = null;
  location.reload();
}

// fetch() with the token.
export async function authFetch(path, init = {}) {
  const headers = new Headers(init.headers || {});
  if (token) headers.set('Authorization', `Bearer ${token}`);
  const response = await fetch(path, { ...init, headers });
  if (response.status === 401 && token) logInAgain();
  return response;
}

// The WebSocket subprotocols of a view session.
export function socketProtocols() {
  return token ? ['voxserve', `bearer.${token}`] : ['voxserve'];
}
