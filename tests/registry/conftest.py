"""The PostgreSQL server the registry's tests run against (tests/pg.py): one per test
process (pytest-xdist worker), started by the first test that asks for it."""

import itertools

import pytest

from .. import pg
from ..conftest import needs

# Every test that uses the server, directly or through another fixture, is marked with it
# (pytest_itemcollected): skipped when PostgreSQL is missing, failed under
# GYROCAL_REQUIRE_DEPS. The registry's SQLite tests, beside them, run without it.
needs_postgres = needs(pg.found(), pg.INSTALL)
_DATABASES = itertools.count()


def pytest_itemcollected(item):
    callspec = getattr(item, "callspec", None)
    on_postgres = callspec is not None and callspec.params.get("backend") == "postgresql"
    if {"postgres_url", "postgres_server"} & set(item.fixturenames) or on_postgres:
        item.add_marker(needs_postgres)


@pytest.fixture(params=["sqlite", "postgresql"])
def backend(request):
    """The registry's back end a test runs on: its name."""
    return request.param


@pytest.fixture
def where(backend, request, tmp_path):
    """An empty registry of the back end: an SQLite file, or a PostgreSQL database of the
    test's own on the process' server, in English order (ICU en-US, as a factory's may be:
    "a-1" before "A1" before "a1x"), which the registry's byte order must not follow."""
    if backend == "sqlite":
        return str(tmp_path / "registry.sqlite")
    server = request.getfixturevalue("postgres_server")
    return server.create_database(f"registry_{next(_DATABASES)}", icu_locale="en-US")


@pytest.fixture(scope="session")
def postgres_server():
    """The running server (:class:`tests.pg.Server`): its port, log, and
    :meth:`~tests.pg.Server.create_database` for a test that needs a database of its own."""
    with pg.Server() as server:
        yield server


@pytest.fixture(scope="session")
def postgres_url(postgres_server) -> str:
    """``postgresql://gyrocal@127.0.0.1:PORT/gyrocal``: the session's database, shared by
    the tests of one process; a test's tables are its own to name and drop."""
    return postgres_server.url()
