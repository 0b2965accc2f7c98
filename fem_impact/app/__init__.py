"""The application: the command line, a run's pipeline and outputs, studies, sweeps, pictures."""
