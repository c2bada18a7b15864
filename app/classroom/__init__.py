"""Who may do what on a shared server: presenter and viewers, bounds on settings, upload checks, lesson links."""
