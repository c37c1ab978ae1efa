"""Basic256Sha256 SignAndEncrypt with self-signed certificates made in the test (cryptography),
and a user name whose password comes from a file: the bridge connects, reads and writes; a
wrong password is refused (never connected, the StatusCode said)."""
from __future__ import annotations

import time

import pytest
from asyncua import ua
from asyncua.crypto.permission_rules import User, UserRole

from support.opcua_certs import self_signed
from support.opcua_servers import wait, LagServer
from tank_control.opcua import config
from tank_control.opcua.bridge import Bridge

#: each test starts an asyncua server (4-6 s of start-up on a busy machine)
pytestmark = pytest.mark.slow

TS = 0.1
SERVER_URI = 'urn:tank_control:test:server'
CLIENT_URI = 'urn:tank_control:test:bridge'


class Users:
    """One user, operator / the password given."""

    def __init__(self, password: str) -> None:
        self.password = password

    def get_user(self, iserver, username=None, password=None, certificate=None):
        if username == 'operator' and password == self.password:
            return User(role=UserRole.User, name=username)
        return None



def secure_server(tmp_path):
    server_cert, server_key = self_signed(tmp_path, 'server', SERVER_URI)

    async def setup(server):
        await server.set_application_uri(SERVER_URI)
        server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
        server.set_identity_tokens([ua.UserNameIdentityToken])
        await server.load_certificate(str(server_cert))
        await server.load_private_key(str(server_key))
    return LagServer(ts=TS, setup=setup, user_manager=Users('correct horse')).start(), server_cert


def bridge_values(tmp_path, server, server_cert, password: str) -> dict:
    client_cert, client_key = self_signed(tmp_path, 'bridge', CLIENT_URI)
    secret = tmp_path / f'password-{len(password)}'
    secret.write_text(password + '\n')
    return {'endpoint': server.endpoint, 'sample_time': TS,
            'measurement.channels': ['y'], 'measurement.y.node_id': server.level_nodeid,
            'manipulated.channels': ['u'], 'manipulated.u.node_id': server.inflow_nodeid,
            'range.u': [0.0, 5.0], 'security.policy': 'Basic256Sha256',
            'security.mode': 'SignAndEncrypt', 'security.certificate': str(client_cert),
            'security.private_key': str(client_key),
            'security.server_certificate': str(server_cert), 'username': 'operator',
            'password.file': str(secret)}


def test_sign_and_encrypt_with_self_signed_certificates_and_a_password_from_a_file(tmp_path):
    server, server_cert = secure_server(tmp_path)
    samples, logs = [], []
    try:
        bridge = Bridge(config.settings_from(bridge_values(tmp_path, server, server_cert,
                                                           'correct horse')),
                        samples.append, lambda level, text: logs.append(text))
        bridge.start()
        try:
            assert bridge.wait_first_attempt(60)
            assert bridge.state == 'connected', bridge.problem
            assert wait(lambda: len(samples) > 5)
            bridge.write({'u': 1.5}, 1)
            assert wait(lambda: [v for _, v in server.snapshot()[1]] == [1.5])
            assert any('Basic256Sha256, SignAndEncrypt' in text for text in logs)
        finally:
            bridge.stop()
        # the server takes nothing else: the same bridge without security is refused
        values = bridge_values(tmp_path, server, server_cert, 'correct horse')
        values['security.policy'] = 'None'
        plain = Bridge(config.settings_from(values), samples.append, lambda level, text: None)
        plain.start()
        try:
            assert plain.wait_first_attempt(60)
            assert plain.state == 'down' and plain.counters['connections'] == 0, plain.problem
        finally:
            plain.stop()
    finally:
        server.close()


def test_a_wrong_password_is_refused(tmp_path):
    server, server_cert = secure_server(tmp_path)
    samples, logs = [], []
    try:
        bridge = Bridge(config.settings_from(bridge_values(tmp_path, server, server_cert,
                                                           'wrong horse')),
                        samples.append, lambda level, text: logs.append(text))
        bridge.start()
        try:
            assert bridge.wait_first_attempt(60)
            assert bridge.state == 'down'
            assert 'BadUserAccessDenied' in bridge.problem or 'BadIdentityToken' in \
                bridge.problem, bridge.problem
            assert wait(lambda: logs)
            assert 'refused by the server' in logs[0] and 'wrong horse' not in ' '.join(logs)
            assert samples == [] and bridge.counters['connections'] == 0
        finally:
            bridge.stop()
    finally:
        server.close()
