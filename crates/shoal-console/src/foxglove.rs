//! `GET /api/foxglove`: the Foxglove live bridge for the Foxglove app (docs/foxglove.md).
//!
//! The Foxglove SDK's server (crate `shoal-foxglove`) listens on a loopback port and
//! cannot check who connects; clients reach it only through this route, which
//! authenticates like every other API route (viewer role; the [`guard`] has run), checks
//! `Origin` as for the live feed, takes one of the bridge's `max_clients` places, and
//! then hands the upgraded socket to the bridge's gateway, which pipes it to the SDK's
//! server and drops the client if it reads too slowly.
//!
//! The Foxglove app cannot set headers on a WebSocket; it sends its token as
//! `?token=...`, which [`token_in_query`] turns into `Authorization: Bearer` before the
//! guard authenticates the request.
//!
//! [`guard`]: crate::guard

use axum::Extension;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Request, State};
use axum::http::{HeaderMap, HeaderValue, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use shoal_foxglove::{BridgeHandle, Frame, SessionEnd, negotiate};
use tracing::{debug, info};

use crate::auth::Identity;
use crate::gate::Refused;
use crate::{ApiError, AppState};

/// The route's path.
pub(crate) const PATH: &str = "/api/foxglove";

/// Moves a `?token=` of `/api/foxglove` into `Authorization: Bearer`, for clients that
/// cannot set headers on a WebSocket (browsers, the Foxglove app). A request that has an
/// Authorization header already keeps it. Layered outside the guard.
pub(crate) async fn token_in_query(mut req: Request, next: Next) -> Response {
    if req.uri().path() == PATH && !req.headers().contains_key(header::AUTHORIZATION) {
        let token = req.uri().query().and_then(|q| {
            serde_urlencoded::from_str::<Vec<(String, String)>>(q)
                .ok()?
                .into_iter()
                .find_map(|(k, v)| (k == "token").then_some(v))
        });
        if let Some(value) = token.and_then(|t| HeaderValue::from_str(&format!("Bearer {t}")).ok())
        {
            req.headers_mut().insert(header::AUTHORIZATION, value);
        }
    }
    next.run(req).await
}

/// Upgrades an authenticated viewer (or better) to the Foxglove WebSocket protocol, with
/// the newest subprotocol both sides speak echoed (`foxglove.sdk.v1.1`,
/// `foxglove.sdk.v1` or `foxglove.websocket.v1`).
pub(crate) async fn foxglove(
    State(app): State<AppState>,
    who: Option<Extension<Identity>>,
    headers: HeaderMap,
    mut upgrade: WebSocketUpgrade,
) -> Response {
    // A page of another site may not open it with the browser's credentials, as for
    // the live feed; tools send no Origin and a bearer token.
    let origin = headers.get(header::ORIGIN);
    if let Some(origin) = origin {
        let host = headers.get(header::HOST).and_then(|h| h.to_str().ok());
        if !origin.to_str().is_ok_and(|o| app.gate.origin_ok(o, host)) {
            app.gate.count(Refused::Origin);
            return ApiError::Forbidden(format!(
                "GET {PATH} from a page of another site (Origin {origin:?}) is refused: add \
                 the Foxglove app's origin to [console] allowed_origins to allow it"
            ))
            .into_response();
        }
    } else if who.as_ref().is_some_and(|w| w.via == "session") {
        app.gate.count(Refused::Origin);
        return ApiError::Forbidden(format!(
            "GET {PATH} with a session cookie needs the Origin header a browser sends; \
             tools send a token (?token= or Authorization: Bearer)"
        ))
        .into_response();
    }
    let Some(bridge) = app.foxglove else {
        return ApiError::NotFound(
            "the Foxglove bridge is off ([foxglove] enabled = false)".into(),
        )
        .into_response();
    };
    let offered: Vec<&str> = upgrade
        .requested_protocols()
        .filter_map(|p| p.to_str().ok())
        .collect();
    let Some(subprotocol) = negotiate(offered) else {
        return ApiError::BadRequest(
            "offer a Foxglove WebSocket subprotocol (foxglove.sdk.v1.1, foxglove.sdk.v1 or \
             foxglove.websocket.v1) in Sec-WebSocket-Protocol"
                .into(),
        )
        .into_response();
    };
    let place = match bridge.admit() {
        Ok(p) => p,
        Err(e) => return ApiError::Busy(e.to_string()).into_response(),
    };
    upgrade.set_selected_protocol(HeaderValue::from_static(subprotocol.as_str()));
    let name = who.map(|w| w.name.clone()).unwrap_or_default();
    upgrade
        .max_message_size(bridge.config().max_client_message_bytes)
        .on_upgrade(move |socket| serve(bridge, place, socket, subprotocol, name))
}

/// Runs one client's session through the bridge's gateway.
async fn serve(
    bridge: BridgeHandle,
    place: shoal_foxglove::ClientPlace,
    socket: WebSocket,
    subprotocol: shoal_foxglove::Subprotocol,
    who: String,
) {
    info!(client = %who, subprotocol = subprotocol.as_str(), "Foxglove client connected");
    let client = shoal_foxglove::adapt(socket, to_axum, from_axum);
    match bridge.serve(place, client, subprotocol).await {
        Ok(SessionEnd::TooSlow) => info!(client = %who, "Foxglove client dropped: too slow"),
        Ok(end) => debug!(client = %who, ?end, "Foxglove client left"),
        Err(e) => info!(client = %who, error = %e, "Foxglove client not served"),
    }
}

fn to_axum(frame: Frame) -> Message {
    match frame {
        Frame::Text(t) => Message::Text(t.into()),
        Frame::Binary(b) => Message::Binary(b),
        Frame::Close => Message::Close(None),
    }
}

fn from_axum(message: Message) -> Option<Frame> {
    match message {
        Message::Text(t) => Some(Frame::Text(t.as_str().to_owned())),
        Message::Binary(b) => Some(Frame::Binary(b)),
        Message::Close(_) => Some(Frame::Close),
        // Pings are answered by axum.
        Message::Ping(_) | Message::Pong(_) => None,
    }
}

#[cfg(test)]
mod tests {
    use axum::Router;
    use axum::body::Body;
    use axum::http::{HeaderMap, Request, header};
    use axum::routing::get;
    use http_body_util::BodyExt;
    use tower::ServiceExt;

    /// What Authorization header the handler behind the middleware sees.
    async fn seen(uri: &str, authorization: Option<&str>) -> String {
        let app = Router::new()
            .route(
                "/api/foxglove",
                get(|h: HeaderMap| async move { seen_header(&h) }),
            )
            .route(
                "/api/fleet",
                get(|h: HeaderMap| async move { seen_header(&h) }),
            )
            .layer(axum::middleware::from_fn(super::token_in_query));
        let mut req = Request::builder().uri(uri);
        if let Some(a) = authorization {
            req = req.header(header::AUTHORIZATION, a);
        }
        let res = app
            .oneshot(req.body(Body::empty()).unwrap_or_default())
            .await
            .unwrap_or_else(|e| match e {});
        let body = res.into_body().collect().await.map(|b| b.to_bytes());
        String::from_utf8_lossy(&body.unwrap_or_default()).into_owned()
    }

    fn seen_header(h: &HeaderMap) -> String {
        h.get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .unwrap_or("none")
            .to_owned()
    }

    #[tokio::test]
    async fn a_query_token_becomes_a_bearer_header_on_the_foxglove_route_only() {
        assert_eq!(
            seen("/api/foxglove?token=abc%2Bd", None).await,
            "Bearer abc+d"
        );
        assert_eq!(seen("/api/foxglove?x=1&token=t1", None).await, "Bearer t1");
        // A header the client sent wins; other routes never read tokens from URLs.
        assert_eq!(
            seen("/api/foxglove?token=t1", Some("Bearer t2")).await,
            "Bearer t2"
        );
        assert_eq!(seen("/api/fleet?token=t1", None).await, "none");
        assert_eq!(seen("/api/foxglove", None).await, "none");
        // A token that cannot be a header value is ignored (then 401 from the guard).
        assert_eq!(seen("/api/foxglove?token=a%0Ab", None).await, "none");
    }
}
