r'''camval's command line: the top floor (reference_models < targets < renderers < harness <
reports < camval); camval.cli parses the arguments, camval/commands/NAME.py runs a subcommand'''
