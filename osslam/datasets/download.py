"""Fetching TUM RGB-D sequences: resumable HTTP download, archive integrity check, safe extraction.

Standard library only. A download goes to ``NAME.tgz.part`` and resumes with an HTTP
``Range`` request after a cut connection (or on the next call); the finished archive is
read completely (gzip CRC and every tar member) before anything is extracted; extraction
rejects absolute paths, ``..``, links leading outside the target and special files, and
goes through a staging folder so a half-extracted sequence never looks present.
"""

from __future__ import annotations

import gzip
import http.client
import logging
import os
import re
import shutil
import tarfile
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from urllib.error import HTTPError, URLError
from urllib.request import Request, urlopen

from osslam.errors import OsslamError

from .catalogue import TUM_BASE_URL, TumEntry

log = logging.getLogger(__name__)

#: Called with (bytes so far, total bytes or None) while downloading.
ProgressCallback = Callable[[int, "int | None"], None]

CHUNK_BYTES = 1 << 20
_CONTENT_RANGE = re.compile(r"bytes (\d+)-(\d+)/(\d+|\*)")


class DownloadError(OsslamError):
    """A download that failed, an archive that is corrupt or unsafe to extract."""


@dataclass
class FetchResult:
    """A fetched sequence: where it lies and whether it was ``present`` already or ``downloaded``."""

    entry: TumEntry
    folder: Path
    status: str
    bytes_downloaded: int = 0


def _range_start_and_total(resp, have: int) -> tuple[int, int | None]:
    """Where a response's body starts in the file, and the file's total size if the server says."""
    if resp.status == 206:
        match = _CONTENT_RANGE.match(resp.headers.get("Content-Range", ""))
        if not match:
            return 0, None
        total = None if match.group(3) == "*" else int(match.group(3))
        return int(match.group(1)), total
    length = resp.headers.get("Content-Length")
    return 0, int(length) if length is not None else None


def download(url: str, dest: str | Path, retries: int = 5, timeout: float = 30.0, retry_delay: float = 1.0,
             on_progress: ProgressCallback | None = None) -> Path:
    """Download ``url`` to ``dest`` through ``dest.part``, resuming after cut connections.

    A ``.part`` file left by an earlier call is resumed too. ``retries`` counts consecutive
    failed attempts (one that received data resets the count). HTTP errors other than a
    stale range (416) are not retried. Raises DownloadError.
    """
    dest = Path(dest)
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # a file where the folder should be, or no permission
        raise DownloadError(f"{dest.parent}: cannot create the folder ({exc.strerror or exc})") from None
    if not os.access(dest.parent, os.W_OK):
        raise DownloadError(f"{dest.parent}: the folder is not writable")
    part = dest.with_name(dest.name + ".part")
    failures = 0
    while True:
        have = part.stat().st_size if part.exists() else 0
        request = Request(url, headers={"Range": f"bytes={have}-"} if have else {})
        received = 0
        try:
            with urlopen(request, timeout=timeout) as resp:
                start, total = _range_start_and_total(resp, have)
                if start != have:
                    log.info("%s: server sent the whole file; starting again", url)
                    have = 0
                with open(part, "ab" if have else "wb") as f:
                    while chunk := resp.read(CHUNK_BYTES):
                        f.write(chunk)
                        received += len(chunk)
                        if on_progress:
                            on_progress(have + received, total)
                if total is not None and have + received < total:
                    raise http.client.IncompleteRead(b"", total - have - received)
            break
        except HTTPError as exc:
            if exc.code == 416 and have:
                log.info("%s: the partial file is not a prefix of this one; starting again", url)
                part.unlink()
                failures += 1
            else:
                raise DownloadError(f"{url}: HTTP {exc.code} {exc.reason}") from None
        except (URLError, OSError, http.client.HTTPException) as exc:
            failures = 0 if received else failures + 1
            reason = getattr(exc, "reason", None) or exc.__class__.__name__
            log.warning("%s: connection lost after %d bytes (%s); resuming", url, have + received, reason)
        if failures > retries:
            raise DownloadError(f"{url}: failed {failures} times in a row; {part} is kept for resuming")
        if failures:
            time.sleep(retry_delay * min(2 ** (failures - 1), 30))
    part.replace(dest)
    return dest


def check_archive(path: str | Path) -> int:
    """Read a ``.tgz`` completely (gzip CRC, every tar member); the number of members, or DownloadError."""
    path = Path(path)
    try:
        with gzip.open(path, "rb") as stream:
            while stream.read(CHUNK_BYTES):
                pass
        count = 0
        with tarfile.open(path, "r:gz") as tar:
            for member in tar:
                count += 1
                if member.isfile():
                    data = tar.extractfile(member)
                    while data.read(CHUNK_BYTES):
                        pass
    except (tarfile.TarError, EOFError, zlib.error, OSError) as exc:
        raise DownloadError(f"{path}: corrupt archive ({exc or exc.__class__.__name__})") from None
    if count == 0:
        raise DownloadError(f"{path}: empty archive")
    return count


def _inside(root: Path, path: Path) -> bool:
    """Whether ``path`` (resolved) lies in ``root`` (resolved)."""
    return path.resolve().is_relative_to(root.resolve())


def check_members(tar: tarfile.TarFile, target: Path) -> None:
    """Reject members that would land outside ``target``: absolute paths, ``..``, escaping links, devices."""
    for member in tar.getmembers():
        name = PurePosixPath(member.name)
        if name.is_absolute() or member.name.startswith(("/", "\\")) or ".." in name.parts:
            raise DownloadError(f"unsafe path in archive: {member.name!r}")
        if not _inside(target, target / name):
            raise DownloadError(f"unsafe path in archive: {member.name!r}")
        if member.ischr() or member.isblk() or member.isfifo():
            raise DownloadError(f"special file in archive: {member.name!r}")
        if member.issym() or member.islnk():
            link = PurePosixPath(member.linkname)
            base = target / name.parent if member.issym() else target
            if link.is_absolute() or not _inside(target, base / link):
                raise DownloadError(f"link leading outside the target in archive: {member.name!r} -> {link}")


def safe_extract(archive: str | Path, target: str | Path) -> None:
    """Extract ``archive`` into ``target`` after :func:`check_members`, with tarfile's ``data`` filter when available."""
    target = Path(target)
    target.mkdir(parents=True, exist_ok=True)
    try:
        with tarfile.open(archive, "r:gz") as tar:
            check_members(tar, target)
            if hasattr(tarfile, "data_filter"):
                tar.extractall(target, filter="data")
            else:
                tar.extractall(target)
    except tarfile.TarError as exc:
        raise DownloadError(f"{archive}: cannot extract ({exc})") from None


def is_present(folder: Path) -> bool:
    """Whether ``folder`` holds an extracted TUM sequence (its rgb.txt and depth.txt)."""
    return (folder / "rgb.txt").is_file() and (folder / "depth.txt").is_file()


def fetch_tum(entry: TumEntry, to: str | Path, base_url: str = TUM_BASE_URL, keep_archive: bool = False,
              on_progress: ProgressCallback | None = None, **download_options) -> FetchResult:
    """Download, check and extract one TUM sequence into ``to/<entry.folder>``; skip it when present.

    ``base_url`` replaces the upstream address (a mirror, or a local server in tests);
    ``download_options`` go to :func:`download`.
    """
    to = Path(to)
    folder = to / entry.folder
    if is_present(folder):
        log.info("%s already present in %s", entry.short, folder)
        return FetchResult(entry, folder, "present")
    archive = to / f"{entry.folder}.tgz"
    size = 0
    if not archive.is_file():
        download(entry.url(base_url), archive, on_progress=on_progress, **download_options)
        size = archive.stat().st_size
    try:
        check_archive(archive)
    except DownloadError:
        archive.unlink()
        raise
    staging = to / f".{entry.folder}.extracting"
    shutil.rmtree(staging, ignore_errors=True)
    try:
        safe_extract(archive, staging)
        if not is_present(staging / entry.folder):
            raise DownloadError(f"{archive}: no {entry.folder}/rgb.txt and depth.txt in the archive")
        shutil.rmtree(folder, ignore_errors=True)
        (staging / entry.folder).replace(folder)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    if not keep_archive:
        archive.unlink()
    log.info("%s extracted to %s", entry.short, folder)
    return FetchResult(entry, folder, "downloaded", size)
