"""The SDK (sqmanip_client) against the real gateway app and a real Perception server."""

import httpx
import numpy as np
import pytest
import sqmanip_client as sdk
from sqmanip.gateway.app import create_app
from sqmanip.perception.synthetic import make_single_view


@pytest.fixture(scope="module")
def scene():
    return make_single_view("cylinder", seed=5)


@pytest.fixture
def sdk_client(client):
    return sdk.Client("http://testserver", http_client=client)


def test_recognize_binary_returns_typed_scene(sdk_client, scene) -> None:
    result = sdk_client.recognize(scene.points, viewpoint=scene.viewpoint, method="mvbb")
    assert isinstance(result, sdk.Scene) and len(result.objects) == 1
    obj = result.objects[0]
    part = obj.parts[0]
    assert isinstance(part, sdk.SuperquadricPart) and part.kind == "superellipsoid"
    T = part.pose.matrix()
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
    assert obj.point_indices.dtype == np.int64 and obj.mean_color is None
    assert result.support_plane is not None and result.support_plane.normal[2] > 0.99


def test_recognize_json_path_with_colors_and_labels(sdk_client, scene) -> None:
    labels = np.where(scene.object_ids >= 0, 0, -1)
    colors = np.full((len(scene.points), 3), 0.5)
    result = sdk_client.recognize(scene.points, colors=colors, labels=labels, method="mvbb")
    assert len(result.objects) == 1
    assert result.objects[0].mean_color == pytest.approx((0.5, 0.5, 0.5), abs=1 / 255)
    assert set(result.objects[0].point_indices) <= set(np.flatnonzero(labels == 0))


def test_bad_request_raises_typed_error_with_detail(sdk_client) -> None:
    with pytest.raises(sdk.BadRequestError) as err:
        sdk_client.recognize(np.array([[0, 0, np.nan]] * 4))
    assert err.value.status == 400 and "finite" in err.value.detail and err.value.field == "points"
    with pytest.raises(ValueError, match="points must have shape"):
        sdk_client.recognize(np.zeros((4, 2)))


def test_unavailable_backend_raises_service_unavailable(dead_backend_client) -> None:
    c = sdk.Client("http://testserver", http_client=dead_backend_client)
    with pytest.raises(sdk.ServiceUnavailableError) as err:
        c.recognize(np.zeros((10, 3)))
    assert err.value.status == 503


def test_unreachable_gateway_raises_connection_error() -> None:
    from sqmanip.launch import free_port

    with pytest.raises(sdk.ConnectionError):
        sdk.Client(f"http://127.0.0.1:{free_port()}", timeout=2).recognize(np.zeros((3, 3)))


async def test_async_client(gateway_settings, scene) -> None:
    app = create_app(gateway_settings)
    async with app.router.lifespan_context(app):
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://testserver") as http:
            client = sdk.AsyncClient("http://testserver", http_client=http)
            result = await client.recognize(scene.points, viewpoint=scene.viewpoint, method="mvbb")
            assert len(result.objects) == 1
            with pytest.raises(sdk.BadRequestError):
                await client.recognize(np.zeros((0, 3)))
            assert (await client.health())["status"] == "ok"


def test_mesh_and_surface_points_lie_on_the_fitted_part(sdk_client, scene) -> None:
    obj = sdk_client.recognize(scene.points, viewpoint=scene.viewpoint, method="mvbb").objects[0]
    mesh = sdk.to_mesh(obj)
    assert mesh.is_watertight and mesh.volume > 0
    pts = sdk.surface_points(obj, 200)
    assert pts.shape == (200, 3)
    lo, hi = mesh.bounds
    assert np.all(pts >= lo - 1e-6) and np.all(pts <= hi + 1e-6)
