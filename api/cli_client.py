"""The client the service commands (``qhsm submit``, ``submit-batch``, ``usage``, ...) talk to
a running service with: made from their ``--url`` and ``--key`` options."""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

from shared.cli_options import CommandError, settings_from_args

if TYPE_CHECKING:
    from api.client import Client

#: Where the commands' API key comes from, as their messages name it.
KEY_OPTION = "the --key option"


@contextmanager
def api_client(args: argparse.Namespace, hint: str = "", **options: Any) -> Iterator[Client]:
    """A client of the API the settings options name, closed at the end; what it raises
    (``ClientError``) ends the command with its message and ``hint``."""
    from api.client import Client, ClientError

    client = Client(settings_from_args(args).api_url, key=args.key, **options)
    try:
        yield client
    except ClientError as error:
        raise CommandError(f"{error}{hint}") from None
    finally:
        client.close()
