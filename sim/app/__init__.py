"""What a user runs and looks at: the `jiggle` command line and everything that only presents results.

`cli` builds the parser from one module per subcommand (`commands/`) and shared argument groups
(`args`); `compare` (metrics, plots, renders, the HTML report), `play`, `describe` and the
`*_outputs` modules write what a person looks at. Imports everything below; nothing imports it."""
