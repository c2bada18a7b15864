"""The panels every tab shares (server.gui): Train (settings, run controls, live plots), Views and Runs."""
