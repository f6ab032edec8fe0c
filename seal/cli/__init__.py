"""Layer 6: the command line. Each subcommand lives in its own module and calls the layers below."""
