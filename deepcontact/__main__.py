"""`python -m deepcontact`: the `dc` command line."""
from deepcontact.cli.main import main

main()
