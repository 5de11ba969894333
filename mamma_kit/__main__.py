from mamma_kit.cli.app import main

main()
