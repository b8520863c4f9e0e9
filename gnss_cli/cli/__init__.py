"""Command-line shells (Typer) over the library; the only place that sets exit codes."""
