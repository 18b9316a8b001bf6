//! `Session.GetCaller`: the caller's own name, role and how it was
//! established, as the security layer saw it; the same through the typed
//! client (`Client::caller`).

use cangate_client::{ConnectOptions, pb};
use cangate_server::security::auth::hash_token;
use cangate_tests::*;
use tonic::Code;

async fn with_token(server: &cangate_server::RunningServer, token: &str) -> cangate_client::Client {
    cangate_client::connect_with(
        &format!("http://{}", server.addr),
        &ConnectOptions {
            token: Some(token.into()),
            ..ConnectOptions::default()
        },
    )
    .await
    .expect("client connects")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn get_caller_names_the_token_and_its_role() {
    let text = format!(
        "{ONE_BUS}\
         [[security.tokens]]\nname = \"wall-screen\"\nrole = \"viewer\"\nsha256 = \"{}\"\n\
         [[security.tokens]]\nname = \"cell-3\"\nrole = \"operator\"\nsha256 = \"{}\"\n",
        hash_token("v-secret"),
        hash_token("o-secret"),
    );
    let server = start_server(&text).await;
    for (token, name, role) in [
        ("v-secret", "wall-screen", pb::CallerRole::Viewer),
        ("o-secret", "cell-3", pb::CallerRole::Operator),
    ] {
        let caller = with_token(&server, token)
            .await
            .caller()
            .await
            .expect("GetCaller");
        assert_eq!(caller.name, name);
        assert_eq!(caller.role(), role);
        assert_eq!(caller.method, "token");
        assert!(caller.authentication);
    }
    // No token, or an unknown one: refused as every call that needs a role.
    let anonymous = client(&server).await;
    let e = anonymous
        .session_client()
        .get_caller(pb::GetCallerRequest {})
        .await
        .expect_err("no token");
    assert_eq!(e.code(), Code::Unauthenticated);
    let e = with_token(&server, "wrong")
        .await
        .session_client()
        .get_caller(pb::GetCallerRequest {})
        .await
        .expect_err("unknown token");
    assert_eq!(e.code(), Code::Unauthenticated);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_authentication_everyone_is_an_anonymous_engineer() {
    let server = start_server(ONE_BUS).await;
    let caller = client(&server).await.caller().await.expect("GetCaller");
    assert_eq!(caller.name, "anonymous");
    assert_eq!(caller.role(), pb::CallerRole::Engineer);
    assert_eq!(caller.method, "none");
    assert!(!caller.authentication);
}
