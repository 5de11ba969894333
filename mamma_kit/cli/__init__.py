"""The `mamma-kit` command line (Typer). One module per command; each is thin:
parse arguments, call the library, print."""
