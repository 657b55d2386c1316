"""Errors a user can cause on the host side (ports, files). Each message says
what is wrong and what to do; the CLIs print it and exit non-zero."""


class HostError(Exception):
    exit_code = 2
