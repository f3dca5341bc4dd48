"""A secured fabric: roles and what each may do, credentials (CA, certificates, passwords), Zenoh configs."""
