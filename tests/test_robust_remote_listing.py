"""Remote listings cost one request per page, not one per key (issue 52, root 4): a stage
folder on S3 is listed in pages of 1,000 objects whatever the number of artifacts, with
a cap on the objects walked; http requests have an overall deadline, so a server that
trickles bytes fails in bounded time."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from test_robust_remotes import _cli, _one_error
from test_share_remotes import AWS_ID, AWS_SECRET, s3_env  # noqa: F401 - fixture

from sonarmap.pipeline.engine.errors import StoreError
from sonarmap.pipeline.engine.share import remote_index
from sonarmap.pipeline.engine.share.push_pull import list_remote
from tests.fixtures.hostile_http import misbehaving_server


def _bucket(env: dict[str, str], keys: int) -> None:
    import boto3

    client = boto3.client(
        "s3",
        endpoint_url=env["AWS_ENDPOINT_URL_S3"],
        aws_access_key_id=AWS_ID,
        aws_secret_access_key=AWS_SECRET,
        region_name="us-east-1",
    )
    for k in range(keys):
        key = f"{k:064x}"
        client.put_object(Bucket="lab", Key=f"x/fuse/{key}/manifest.json", Body=b"{}")
        if k % 2:  # a second file; every tenth artifact without a manifest (a push cut short)
            client.put_object(Bucket="lab", Key=f"x/fuse/{key}/fused.parquet", Body=b"p")
    client.delete_object(Bucket="lab", Key=f"x/fuse/{7:064x}/manifest.json")


@pytest.fixture
def counted(
    s3_env: dict[str, str],  # noqa: F811
    monkeypatch: pytest.MonkeyPatch,
) -> Iterator[list[str]]:
    import s3fs

    for name, value in s3_env.items():
        monkeypatch.setenv(name, value)
    s3fs.S3FileSystem.clear_instance_cache()
    calls: list[str] = []
    real = s3fs.S3FileSystem._call_s3

    async def counting(self: Any, method: str, *args: Any, **kwargs: Any) -> Any:
        calls.append(method)
        return await real(self, method, *args, **kwargs)

    monkeypatch.setattr(s3fs.S3FileSystem, "_call_s3", counting)
    yield calls
    s3fs.S3FileSystem.clear_instance_cache()


def test_an_s3_stage_folder_is_listed_by_pages_not_by_key(
    s3_env: dict[str, str],  # noqa: F811
    counted: list[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    _bucket(s3_env, 250)
    monkeypatch.setattr(remote_index, "_PAGE", 100)
    listed = list_remote("s3://lab/x")
    assert len(listed) == 249 and f"fuse/{7:064x}" not in listed
    assert listed == sorted(listed) and all(a.startswith("fuse/") for a in listed)
    # 375 objects in pages of 100, and one listing of the stages: 5 or 6 requests, not 250.
    assert len(counted) <= 8, counted
    assert counted.count("list_objects_v2") == len(counted)


def test_an_s3_listing_over_the_object_cap_is_refused(
    s3_env: dict[str, str],  # noqa: F811
    counted: list[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    _bucket(s3_env, 30)
    monkeypatch.setattr(remote_index, "_PAGE", 10)
    monkeypatch.setattr(remote_index, "MAX_LISTED_OBJECTS", 20)
    with pytest.raises(StoreError, match=r"remote folder 'fuse' lists over 20 objects"):
        list_remote("s3://lab/x")
    assert len(counted) <= 4, counted  # stopped at the cap, not walked to the end


@pytest.fixture
def trickling_server() -> Iterator[int]:
    """Answers every request with headers and then one byte every 0.3 s, for good."""
    with misbehaving_server("trickle") as port:
        yield port


def test_an_http_server_that_trickles_bytes_fails_in_bounded_time(
    trickling_server: int, tmp_path: Path
) -> None:
    env = {**os.environ, "SONARMAP_REMOTE_TIMEOUT_S": "1"}
    url = f"http://127.0.0.1:{trickling_server}/lab"
    t0 = time.monotonic()
    res = _cli(env, "pull", url, "--store", str(tmp_path / "s"), timeout=60)
    took = time.monotonic() - t0
    line = _one_error(res)
    assert f"remote {url}: pull: timed out" in line, line
    assert took < 15, took
