"""Dynamics domain <-> proto conversion (dynamics.proto): the arguments and result of
``SQPDNet.predict`` survive the wire, and size/shape errors name the field."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from sqmanip.errors import ValidationError
from sqmanip.geometry.transforms import quat_to_matrix
from sqmanip.rpc import convert
from sqmanip.v1 import dynamics_pb2


def _wire(msg):
    return type(msg).FromString(msg.SerializeToString())


def scene(n: int = 3, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = quat_to_matrix(
        torch.as_tensor(q / np.linalg.norm(q, axis=1, keepdims=True))
    ).numpy()
    poses[:, :3, 3] = rng.uniform(-0.3, 0.3, (n, 3))
    params = np.column_stack([
        rng.uniform(0.01, 0.05, (n, 3)), rng.uniform(0.2, 1.0, (n, 2)),
        rng.uniform(-0.3, 0.3, n), rng.uniform(0, 2, n), rng.uniform(0, 3, n), np.full(n, 0.01),
    ])  # fmt: skip
    kinds = np.arange(n) % 3
    return poses, params, kinds


def test_predict_request_round_trips_poses_params_kinds_and_actions() -> None:
    poses, params, kinds = scene(3)
    actions = np.random.default_rng(1).normal(size=(7, 6)).astype(np.float32)
    msg = convert.predict_request_to_proto(poses, params, actions, kinds, model="physics")
    assert len(msg.actions) == 7 * 6 * 4
    args = convert.predict_request_from_proto(_wire(msg))
    np.testing.assert_allclose(args.poses, poses, atol=1e-12)
    np.testing.assert_allclose(args.params, params, atol=0)
    np.testing.assert_array_equal(args.kinds, kinds)
    np.testing.assert_array_equal(args.actions, actions)
    assert args.actions.dtype == np.float32 and args.model == "physics"


def test_empty_model_means_sqpdnet_and_default_kinds_are_superellipsoids() -> None:
    poses, params, _ = scene(2)
    msg = convert.predict_request_to_proto(poses, params, np.zeros((1, 6)), model="")
    args = convert.predict_request_from_proto(_wire(msg))
    assert args.model == "sqpdnet" and args.kinds.tolist() == [0, 0]


def test_predict_response_round_trips_poses_and_failure_flags() -> None:
    nxt = np.random.default_rng(2).normal(size=(5, 3, 4, 4)).astype(np.float32)
    failed = np.array([0, 1, 0, 0, 1], dtype=bool)
    msg = _wire(
        convert.predict_response_to_proto(nxt, model="physics", failed=failed, latency_ms=3)
    )
    poses, flags = convert.predict_response_from_proto(msg)
    np.testing.assert_array_equal(poses, nxt)
    np.testing.assert_array_equal(flags, failed)
    assert msg.model == "physics" and msg.latency_ms == 3
    _, none = convert.predict_response_from_proto(
        convert.predict_response_to_proto(torch.as_tensor(nxt), model="sqpdnet")
    )
    assert none is None


@pytest.mark.parametrize(
    ("args", "field"),
    [
        ((np.zeros((2, 4, 3)), np.zeros((2, 9)), np.zeros((1, 6))), "poses"),
        ((np.tile(np.eye(4), (2, 1, 1)), np.ones((3, 9)), np.zeros((1, 6))), "params"),
        ((np.tile(np.eye(4), (2, 1, 1)), np.ones((2, 9)), np.zeros((1, 5))), "actions"),
        ((np.tile(np.eye(4), (2, 1, 1)), np.ones((2, 9)), [[0, 0, 0, np.nan, 0, 0]]), "actions"),
        ((np.tile(np.eye(4), (1, 1, 1)), -np.ones((1, 9)), np.zeros((1, 6))), r"params\[0\]"),
    ],
)
def test_client_side_shape_and_value_errors_name_the_field(args, field) -> None:
    with pytest.raises(ValidationError, match=rf"^{field}"):
        convert.predict_request_to_proto(*args)


def test_server_side_byte_size_mismatches_name_the_field() -> None:
    poses, params, _ = scene(2)
    msg = convert.predict_request_to_proto(poses, params, np.zeros((3, 6)))
    msg.num_actions = 4
    with pytest.raises(
        ValidationError, match=r"actions: expected 4 x 6 float32 = 96 bytes, got 72"
    ):
        convert.predict_request_from_proto(_wire(msg))
    msg.num_actions = 3
    msg.objects[1].a3 = float("inf")
    with pytest.raises(ValidationError, match=r"objects\[1\]: expected finite"):
        convert.predict_request_from_proto(_wire(msg))
    bad = dynamics_pb2.PredictResponse(num_actions=2, num_objects=1, poses=b"\0" * 64)
    with pytest.raises(ValidationError, match=r"^poses: expected 2 x 1 x 4 x 4"):
        convert.predict_response_from_proto(bad)
