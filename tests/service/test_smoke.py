"""The service starts on both databases, answers health without a token and lists coaches."""


def test_health_and_coaches(client, tokens):
    health = client.get("/api/v1/health")
    assert health.status_code == 200 and health.json()["status"] == "ok"
    assert client.get("/api/v1/coaches").status_code == 401
    reply = client.get("/api/v1/coaches", headers=tokens["viewer"])
    assert reply.status_code == 200 and reply.json() == []
    ready = client.get("/api/v1/ready").json()
    assert ready["migrations"] == "0004" and ready["model_version"] == 1
